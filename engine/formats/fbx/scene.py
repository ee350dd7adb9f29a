"""FBX scenes: the document tree (binary or ASCII FBX 7.x, ASCII FBX 6.x through
:mod:`.legacy`) read as a character and its takes.

:func:`read_fbx` returns the same :class:`~engine.formats.gltf.Character` the glTF reader does:
the skeleton whose zero-rotation pose is the bind pose, the skinned meshes in that pose, and
every animation stack ("take") as a :class:`~engine.motion.Motion` sampled at the file's frame
rate.

How the tree is read (the FBX SDK's model, as Blender's and ufbx's readers implement it):

* **Objects and connections.** ``Objects`` holds every object by its 64-bit id; a
  ``Connections`` record ``C: "OO", child, parent`` links two objects and ``C: "OP", child,
  parent, "property"`` links an object to a parent's property. Properties (``Properties70``)
  fall back on the ``Definitions`` templates of their object type.
* **Joints.** Models of type ``LimbNode``, ``Root`` (and FBX 6's ``Limb``), the models skin
  clusters bind to, and their ``Null`` (or ``LimbNode``) ancestors below the scene root are
  the skeleton's joints (a Blender armature is such a ``Null``). Several top joints get a
  common new ``root`` joint at the origin.
* **Transforms.** A model's local matrix is ``T * Roff * Rp * Rpre * R * Rpost^-1 * Rp^-1 *
  Soff * Sp * S * Sp^-1`` (``Lcl Translation``, ``RotationOffset``, ``RotationPivot``,
  ``PreRotation``, ``Lcl Rotation`` in its ``RotationOrder``, ``PostRotation``,
  ``ScalingOffset``, ``ScalingPivot``, ``Lcl Scaling``; angles in degrees; pre- and
  post-rotations in XYZ order; with ``RotationActive`` off the pre- and post-rotations and the
  rotation order are not used, as in Blender's importer). ``InheritType`` 2 (``Rrs``: Maya's
  segment scale compensation) leaves the parent's own scaling out of the child; 0 and 1 are
  the ordinary product.
* **Bind pose.** A joint's bind matrix is its skin clusters' ``TransformLink`` (its world
  matrix when the skin was bound), else its ``Pose``/``BindPose`` matrix, else its rest
  transform under its parent's bind matrix. A skinned mesh's vertices in the bind pose are
  ``TransformLink * Transform * v`` of its first cluster.
* **Takes.** Each ``AnimationStack`` (the animation of its first ``AnimationLayer``) animates
  ``Lcl Translation``, ``Lcl Rotation`` and ``Lcl Scaling`` through ``AnimationCurveNode``
  objects and one ``AnimationCurve`` per component. Curves are evaluated as FBX defines them:
  constant (standard or "next"), linear and cubic keys (Bezier from the stored slopes, in
  value per second, and their weights; TCB keys from their tension, continuity and bias),
  holding the first and last values outside the keys. A take is sampled from its
  ``LocalStart`` to ``LocalStop`` (else its keys' span) at the file's frame rate
  (``GlobalSettings/TimeMode``, or ``CustomFrameRate``); FBX time is in
  :data:`~.nodes.FBX_TICKS_PER_SECOND` ticks. Takes that move no joint are left out (noted).
* **Axes and units.** ``GlobalSettings`` ``UpAxis``/``FrontAxis``/``CoordAxis`` (and their
  signs) give the file's up, front and right axes, which become the engine's +Y, +Z and +X;
  ``UnitScaleFactor`` is centimetres per file unit. Everything is converted to metres.

A file with no joints raises :class:`~engine.errors.FBXError` saying what the file holds.
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import limits
from ...errors import FBXError
from ...fileio import reading
from ...motion import Motion
from ...skeleton import Skeleton
from ...units import SourceFrame, up_axis_rotation
from ..figure import with_lying_doubt
from ..gltf import (POSITION_LAYOUT, ROTATION_LAYOUT, Character, Mesh, _frozen, _local_translations,
                    _matrix_to_quat, _plural, _polar, _pose_from_world, _pose_motion)
from .ascii import is_ascii_fbx, parse_ascii
from .binary import is_binary_fbx, parse_binary
from .legacy import from_fbx6
from .nodes import FBX_TICKS_PER_SECOND, Node

__all__ = ["read_fbx", "parse_fbx", "take_motion", "DEFAULT_FPS"]

#: the frame rate of a file whose TimeMode is the default one
DEFAULT_FPS = 30.0
#: frames per second of each ``GlobalSettings/TimeMode`` (the FBX SDK's ``FbxTime::EMode``)
_TIME_MODES = {1: 120.0, 2: 100.0, 3: 60.0, 4: 50.0, 5: 48.0, 6: 30.0, 7: 30.0,
               8: 30.0 / 1.001, 9: 30.0 / 1.001, 10: 25.0, 11: 24.0, 12: 1000.0,
               13: 24.0 / 1.001, 15: 96.0, 16: 72.0, 17: 60.0 / 1.001, 18: 120.0 / 1.001}
_CUSTOM_MODE = 14
#: scipy's extrinsic axis sequence of each ``RotationOrder`` (eEulerXYZ rotates about X first)
_EULER_ORDERS = {0: "xyz", 1: "xzy", 2: "yzx", 3: "yxz", 4: "zxy", 5: "zyx", 6: "xyz"}
_JOINT_TYPES = ("LimbNode", "Limb", "Root", "Null")
#: the model types that are joints by themselves (``Limb``: FBX 6's)
_SKELETON_TYPES = ("LimbNode", "Limb", "Root")
#: a model's transform properties and their defaults
_TRANSFORM = {"Lcl Translation": (0, 0, 0), "Lcl Rotation": (0, 0, 0), "Lcl Scaling": (1, 1, 1),
              "RotationOffset": (0, 0, 0), "RotationPivot": (0, 0, 0),
              "ScalingOffset": (0, 0, 0), "ScalingPivot": (0, 0, 0), "PreRotation": (0, 0, 0),
              "PostRotation": (0, 0, 0)}
_ANIMATED = ("Lcl Translation", "Lcl Rotation", "Lcl Scaling")
# AnimationCurve key flags (FbxAnimCurveDef)
_CONSTANT, _LINEAR, _CUBIC = 0x2, 0x4, 0x8
_CONSTANT_NEXT = 0x100
_TANGENT_TCB, _TANGENT_USER = 0x200, 0x400
_CLAMP, _TIME_INDEPENDENT, _CLAMP_PROGRESSIVE = 0x1000, 0x2000, 0x4000
_WEIGHTED_RIGHT, _WEIGHTED_NEXT_LEFT = 0x1000000, 0x2000000
#: how far a bind matrix may stray from a uniformly scaled rotation
_SCALE_TOL = 1e-3
#: a joint gets position channels when its local translation strays this far (a fraction of
#: the character's size) from its bind offset
_MOVE_TOL = 1e-5
#: [ticks] the largest key time taken (about a thousand years)
_MAX_TICKS = 2 ** 60
#: longest take sampled (about 5.5 hours at 30 fps)
_MAX_FRAMES = 600_000


# =========================================================================== the document
def parse_fbx(data: bytes, path=None) -> Node:
    """The document tree of a binary or ASCII FBX 7.x file's bytes.

    Raises:
        FBXError: for anything that is not FBX 7.x, or malformed.
    """
    if is_binary_fbx(data[:32]):
        return parse_binary(data, path)
    if is_ascii_fbx(data[:4096]):
        return parse_ascii(data, path)
    if not data.strip():
        raise FBXError("the file is empty; expected FBX 7.x (binary or ASCII)", path)
    raise FBXError("not an FBX file (expected the header 'Kaydara FBX Binary' or ASCII FBX "
                   "text starting with '; FBX' or 'FBXHeaderExtension')", path)


def _name_class(value) -> tuple[str, str]:
    """An object's ``(name, class)`` from its ``"Name\\x00\\x01Class"`` property."""
    text = value if isinstance(value, str) else ""
    name, _, cls = text.partition("\x00\x01")
    return name, cls


def _properties(node: Node | None) -> dict[str, list]:
    """``Properties70`` of ``node`` as name -> values (the values after the 4 type fields)."""
    out: dict[str, list] = {}
    block = node.find("Properties70") if node is not None else None
    if block is None:
        return out
    for p in block.find_all("P"):
        if len(p.props) >= 4 and isinstance(p.props[0], str):
            out[p.props[0]] = p.props[4:]
    return out


class _Doc:
    """The objects, connections, templates and settings of one file."""

    def __init__(self, root: Node, path, ascii_form: bool):
        self.path = path
        self.ascii_form = ascii_form
        self.objects: dict[int, Node] = {}
        objects = root.find("Objects")
        for node in objects.children if objects is not None else ():
            if node.props and _is_id(node.props[0]):
                self.objects[int(node.props[0])] = node
        self.children: dict[int, list[tuple[int, str | None]]] = {}
        self.parents: dict[int, list[tuple[int, str | None]]] = {}
        connections = root.find("Connections")
        for c in connections.find_all("C") if connections is not None else ():
            if len(c.props) < 3 or c.props[0] not in ("OO", "OP") or \
                    not (_is_id(c.props[1]) and _is_id(c.props[2])):
                continue
            prop = c.props[3] if c.props[0] == "OP" and len(c.props) > 3 and \
                isinstance(c.props[3], str) else None
            child, parent = int(c.props[1]), int(c.props[2])
            self.children.setdefault(parent, []).append((child, prop))
            self.parents.setdefault(child, []).append((parent, prop))
        self.templates: dict[str, dict[str, list]] = {}
        definitions = root.find("Definitions")
        for kind in definitions.find_all("ObjectType") if definitions is not None else ():
            template = kind.find("PropertyTemplate")
            if kind.props and template is not None:
                self.templates[str(kind.props[0])] = _properties(template)
        self.settings = _properties(root.find("GlobalSettings"))

    def error(self, problem: str, node: Node | None = None) -> FBXError:
        where = None
        if node is not None and node.offset is not None:
            where = f"{node.name} at {'line' if self.ascii_form else 'byte'} {node.offset}"
        return FBXError(problem, self.path, where=where)

    def props(self, node: Node) -> dict[str, list]:
        """The node's properties over its type's template."""
        merged = dict(self.templates.get(node.name, {}))
        merged.update(_properties(node))
        return merged

    def kind(self, oid: int) -> tuple[str, str, str]:
        """``(record name, object name, subtype)`` of object ``oid``: ``("Model", "Hips",
        "LimbNode")``."""
        node = self.objects[oid]
        name, _ = _name_class(node.props[1] if len(node.props) > 1 else "")
        sub = node.props[2] if len(node.props) > 2 and isinstance(node.props[2], str) else ""
        return node.name, name, sub

    def linked(self, oid: int, record: str, *, up: bool, prop: bool | None = None) -> list[int]:
        """Objects connected to ``oid`` whose record is ``record`` (parents when ``up``)."""
        links = (self.parents if up else self.children).get(oid, [])
        return [o for o, p in links if o in self.objects and self.objects[o].name == record and
                (prop is None or (p is not None) == prop)]


def _is_id(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _vector(values: dict[str, list], name: str, default) -> np.ndarray:
    """A 3-vector property (the default when absent or not three numbers; it may be out of
    range: see :func:`_model`)."""
    v = values.get(name)
    if v is None or len(v) < 3:
        return np.array(default, dtype=float)
    try:
        return np.array([float(x) for x in v[:3]])
    except (TypeError, ValueError, OverflowError):
        return np.array(default, dtype=float)


def _number(values: dict[str, list], name: str, default: float) -> float:
    """A number property (the default when absent, malformed or not finite)."""
    v = values.get(name)
    try:
        out = float(v[0])
    except (TypeError, ValueError, IndexError, OverflowError):
        return default
    return out if np.isfinite(out) else default


def _array(doc: _Doc, node: Node, name: str, *, integer: bool = False,
           required: bool = True) -> np.ndarray | None:
    """The numeric array child ``name`` of ``node`` (``None`` when absent and not required)."""
    child = node.find(name)
    if child is None or not child.props:
        if required:
            raise doc.error(f"no {name} array (expected one in every {node.name})", node)
        return None
    value = child.props[0]
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf":
        raise doc.error(f"{name} is not an array of numbers", child)
    if integer:
        if value.dtype.kind == "f":
            if not np.all(np.abs(value) <= 2.0 ** 62) or np.any(value != np.round(value)):
                raise doc.error(f"{name} holds numbers that are not whole or are out of range",
                                child)
        return value.astype(np.int64)
    out = value.astype(float)
    if not np.all(np.isfinite(out)) or np.any(np.abs(out) > limits.MAX_MAGNITUDE * 1e3):
        raise doc.error(f"{name} holds numbers that are not finite or are out of range", child)
    return out


def _matrix16(doc: _Doc, node: Node, name: str) -> np.ndarray | None:
    """A 4x4 matrix stored as 16 column-major values (``None`` when absent)."""
    values = _array(doc, node, name, required=False)
    if values is None:
        return None
    if len(values) != 16:
        raise doc.error(f"{name} has {len(values)} values (a matrix has 16)", node.find(name))
    return values.reshape(4, 4).T.copy()


# =========================================================================== axes and rates
def _axis_frame(doc: _Doc) -> tuple[np.ndarray, float, str]:
    """``(A, s, text)``: the 3x3 matrix taking file axes to the engine's (+Y up, +Z front, +X
    right), metres per file unit, and a sentence saying what the file declares."""
    st = doc.settings

    def axis(name: str, default: int) -> tuple[int, float]:
        index = int(_number(st, name, default))
        sign = _number(st, name + "Sign", 1.0)
        if index not in (0, 1, 2):
            raise doc.error(f"GlobalSettings {name} is {index} (expected 0, 1 or 2: X, Y or Z)")
        return index, (1.0 if sign >= 0 else -1.0)

    up, front, coord = axis("UpAxis", 1), axis("FrontAxis", 2), axis("CoordAxis", 0)
    if len({up[0], front[0], coord[0]}) != 3:
        raise doc.error("GlobalSettings UpAxis, FrontAxis and CoordAxis name the same axis "
                        "twice")
    A = np.zeros((3, 3))
    A[0, coord[0]], A[1, up[0]], A[2, front[0]] = coord[1], up[1], front[1]
    unit = _number(st, "UnitScaleFactor", 1.0)
    if not 1e-6 <= unit <= 1e6:
        raise doc.error(f"GlobalSettings UnitScaleFactor is {unit!r} (expected centimetres "
                        "per unit, a positive number)")
    names = "XYZ"
    text = (f"FBX GlobalSettings: up {'+-'[up[1] < 0]}{names[up[0]]}, front "
            f"{'+-'[front[1] < 0]}{names[front[0]]}, {unit:g} cm per unit; converted to "
            "metres, +Y up")
    return A, unit / 100.0, text


def _frame_rate(doc: _Doc) -> float:
    mode = int(_number(doc.settings, "TimeMode", 0))
    custom = _number(doc.settings, "CustomFrameRate", -1.0)
    if mode in _TIME_MODES:
        return _TIME_MODES[mode]
    if (mode == _CUSTOM_MODE or mode == 0) and 1.0 / limits.MAX_FRAME_TIME <= custom <= 1000:
        return custom
    return DEFAULT_FPS


def _to_engine(m: np.ndarray, A: np.ndarray, s: float) -> np.ndarray:
    """File world matrices ``(..., 4, 4)`` in engine axes and metres."""
    out = np.array(m, dtype=float, copy=True)
    out[..., :3, :3] = A @ m[..., :3, :3] @ A.T
    out[..., :3, 3] = s * (m[..., :3, 3] @ A.T)
    return out


# =========================================================================== transforms
def _euler(angles: np.ndarray, order: str) -> np.ndarray:
    """``(N, 3)`` X, Y, Z angles [deg] -> ``(N, 3, 3)`` rotation matrices in ``order``."""
    from scipy.spatial.transform import Rotation     # imported when an FBX file is read
    idx = ["xyz".index(a) for a in order]
    return Rotation.from_euler(order, angles[:, idx], degrees=True).as_matrix()


@dataclass
class _Model:
    """A model's transform settings (file units, degrees)."""

    oid: int
    name: str
    subtype: str
    translation: np.ndarray
    rotation: np.ndarray
    scaling: np.ndarray
    rotation_offset: np.ndarray
    rotation_pivot: np.ndarray
    scaling_offset: np.ndarray
    scaling_pivot: np.ndarray
    pre: np.ndarray          # (3, 3) matrix
    post_inv: np.ndarray     # (3, 3) matrix
    order: str
    inherit: int

    def local(self, T=None, R=None, S=None) -> np.ndarray:
        """``(N, 4, 4)`` local matrices for ``(N, 3)`` translations, rotations [deg] and
        scalings (the model's own values where ``None``)."""
        n = max(len(x) for x in (T, R, S) if x is not None) if any(
            x is not None for x in (T, R, S)) else 1
        T = np.broadcast_to(self.translation if T is None else T, (n, 3))
        R = np.broadcast_to(self.rotation if R is None else R, (n, 3))
        S = np.broadcast_to(self.scaling if S is None else S, (n, 3))
        Q = self.pre @ _euler(np.asarray(R, dtype=float), self.order) @ self.post_inv
        a = T + self.rotation_offset + self.rotation_pivot
        b = -self.rotation_pivot + self.scaling_offset + self.scaling_pivot
        out = np.zeros((n, 4, 4))
        out[:, :3, :3] = Q * S[:, None, :]
        out[:, :3, 3] = a + np.einsum("nab,nb->na", Q, b - S * self.scaling_pivot)
        out[:, 3, 3] = 1.0
        return out


def _model(doc: _Doc, oid: int) -> _Model:
    node = doc.objects[oid]
    _, name, sub = doc.kind(oid)
    p = doc.props(node)
    active = bool(_number(p, "RotationActive", 0.0))
    order = int(_number(p, "RotationOrder", 0.0)) if active else 0
    vectors = {key: _vector(p, key, default) for key, default in _TRANSFORM.items()}
    for key, v in vectors.items():
        if not np.all(np.abs(v) <= limits.MAX_MAGNITUDE):
            raise doc.error(f"the {key} of model {name!r} is {v.tolist()} (expected finite "
                            f"numbers of magnitude at most {limits.MAX_MAGNITUDE:g})", node)
    pre = _euler(vectors["PreRotation"][None], "xyz")[0] if active else np.eye(3)
    post = _euler(vectors["PostRotation"][None], "xyz")[0] if active else np.eye(3)
    return _Model(oid=oid, name=name, subtype=sub,
                  translation=vectors["Lcl Translation"], rotation=vectors["Lcl Rotation"],
                  scaling=vectors["Lcl Scaling"], rotation_offset=vectors["RotationOffset"],
                  rotation_pivot=vectors["RotationPivot"],
                  scaling_offset=vectors["ScalingOffset"], scaling_pivot=vectors["ScalingPivot"],
                  pre=pre, post_inv=post.T, order=_EULER_ORDERS.get(order, "xyz"),
                  inherit=int(_number(p, "InheritType", 1.0)))


def _world(model: _Model, local: np.ndarray, parent_world: np.ndarray | None,
           parent_scaling: np.ndarray | None) -> np.ndarray:
    """``(N, 4, 4)`` world matrices of ``model`` from its local matrices and its parent's world
    matrices (``None`` at the scene root); ``parent_scaling`` ``(N, 3)`` is the parent's own
    ``Lcl Scaling`` (left out of a child whose InheritType is 2, ``Rrs``)."""
    if parent_world is None:
        return local.copy()
    world = parent_world @ local
    if model.inherit == 2 and parent_scaling is not None:
        with np.errstate(divide="ignore", invalid="ignore"):    # a zero scale: not finite
            unscaled = parent_world[..., :3, :3] / parent_scaling[:, None, :]
        world[..., :3, :3] = unscaled @ local[..., :3, :3]
    return world


# =========================================================================== curves
def _curve(doc: _Doc, node: Node):
    """``(times [ticks] (K,), values (K,), flags (K,), data (K, 4))`` of an AnimationCurve."""
    times = _array(doc, node, "KeyTime", integer=True)
    values = _array(doc, node, "KeyValueFloat")
    if len(times) != len(values):
        raise doc.error(f"{len(times)} key times but {len(values)} key values", node)
    if np.any(np.abs(times) > _MAX_TICKS):
        raise doc.error("key times beyond a thousand years", node)
    if np.any(np.diff(times) <= 0):
        raise doc.error("key times that do not increase", node)
    K = len(times)
    flags = np.full(K, _LINEAR, dtype=np.int64)
    data = np.zeros((K, 4))
    raw_flags = _array(doc, node, "KeyAttrFlags", integer=True, required=False)
    raw_data = node.find("KeyAttrDataFloat")
    counts = _array(doc, node, "KeyAttrRefCount", integer=True, required=False)
    if raw_flags is not None and counts is not None and raw_data is not None and K:
        attr = raw_data.props[0] if raw_data.props else None
        if not isinstance(attr, np.ndarray) or len(attr) != 4 * len(raw_flags) or \
                len(counts) != len(raw_flags) or np.any(counts < 0) or counts.sum() < K:
            raise doc.error("key attributes (KeyAttrFlags, KeyAttrDataFloat, "
                            "KeyAttrRefCount) that do not cover the keys", node)
        if attr.dtype.kind not in "biuf" or (attr.dtype != np.float32 and not np.all(
                np.abs(attr.astype(float)) <= np.finfo(np.float32).max)):
            raise doc.error("KeyAttrDataFloat holds values that are not 32-bit floats", node)
        # the attribute each key takes (an attribute serves its count of keys in turn),
        # found without repeating them: a count may be far larger than the keys
        which = np.searchsorted(np.cumsum(counts), np.arange(K), side="right")
        flags = raw_flags[which] & 0xFFFFFFFF
        data = np.asarray(attr, dtype=np.float32).reshape(-1, 4)[which]
    return times, values, flags, data


def _auto_slopes(t, v, flags, bias, weight_l, weight_r):
    """Auto-tangent slopes [value/s] of interior keys ``(N,)`` from their neighbours (the
    FBX SDK's rule, as ufbx reads it): the chord through the neighbours, blended with the
    one-sided slopes and pushed by ``bias`` (the stored slope) unless the key is
    time-independent; zero on a key equal to a neighbour (clamped); clamped so that the curve
    does not overshoot its neighbours (clamp-progressive, with the keys' tangent weights
    ``weight_l``, ``weight_r``)."""
    tp, t0, tn = t[:-2], t[1:-1], t[2:]
    vp, v0, vn = v[:-2], v[1:-1], v[2:]
    f = flags[1:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (vn - vp) / (tn - tp)
        left, right = (v0 - vp) / (t0 - tp), (vn - v0) / (tn - t0)
        delta = (t0 - tp) / (tn - tp)
        blended = 0.5 * slope + 0.5 * (left * (1 - delta) + right * delta)
        weight = np.abs(bias) / 100.0
        target = np.where(bias > 0, right, left)
        pushed = np.where(weight > 1e-4, blended * (1 - weight) + target * weight, blended)
        extra = np.maximum(weight - 5.0, 0.0)
        sign = np.where(np.abs(target - blended) > 1e-5, target - blended, bias)
        pushed = pushed + extra * extra * np.where(sign > 0, 1.0, -1.0) * 40.0
        slope = np.where(f & _TIME_INDEPENDENT, slope, pushed)
        sign = np.where(slope >= 0, 1.0, -1.0)
        range_l, range_r = weight_l * (t0 - tp), weight_r * (tn - t0)
        limit_l = np.where(range_l > 0, sign * (v0 - vp) / range_l, 0.0)
        limit_r = np.where(range_r > 0, sign * (vn - v0) / range_r, 0.0)
        limit = np.minimum(np.where(limit_l > 0, limit_l, 0.0),
                           np.where(limit_r > 0, limit_r, 0.0))
        clamped = sign * np.minimum(np.abs(slope), limit)
    slope = np.where((f & _CLAMP_PROGRESSIVE) != 0, clamped, slope)
    flat = ((f & _CLAMP) != 0) & (np.minimum(np.abs(vp - v0), np.abs(vn - v0)) <= 0)
    return np.nan_to_num(np.where(flat, 0.0, slope))


def _tangents(times, values, flags, data):
    """Per key: the right tangent's slope [value/s] and weight (a fraction of the segment
    after it) and the left tangent's slope and weight (of the segment before it), by each
    key's interpolation and tangent mode (see :func:`_evaluate`)."""
    K = len(times)
    t = times / FBX_TICKS_PER_SECOND
    v = values
    packed = np.ascontiguousarray(data[:, 2], dtype=np.float32).view(np.uint32)
    packed = packed.astype(np.int64)
    weight_r = np.where(flags & _WEIGHTED_RIGHT, (packed & 0xFFFF) * 1e-4, 1 / 3)
    weight_nl = np.where(flags & _WEIGHTED_NEXT_LEFT, (packed >> 16) * 1e-4, 1 / 3)
    stored_r, stored_nl = data[:, 0].astype(float), data[:, 1].astype(float)
    constant, cubic = (flags & _CONSTANT) != 0, (flags & _CUBIC) != 0
    linear = ~constant & ~cubic
    tcb, user = cubic & ((flags & _TANGENT_TCB) != 0), cubic & ((flags & _TANGENT_USER) != 0)
    auto = cubic & ~tcb & ~user
    with np.errstate(divide="ignore", invalid="ignore"):
        secant = np.nan_to_num(np.diff(v) / np.diff(t))        # (K - 1,) after each key
    after = np.append(secant, 0.0)
    before = np.insert(secant, 0, 0.0)
    slope_r = np.where(constant, 0.0, np.where(linear, after, stored_r))
    weight_r = np.where(cubic, weight_r, 1 / 3)
    next_left = np.where(cubic & ~tcb, stored_nl, np.where(linear, after, 0.0))
    next_weight = np.where(cubic & ~tcb, weight_nl, 1 / 3)
    slope_l = np.insert(next_left[:-1], 0, 0.0)                 # carried from the key before
    weight_l = np.insert(next_weight[:-1], 0, 1 / 3)
    if np.any(tcb):
        edge = np.zeros(K, dtype=bool)
        edge[[0, -1]] = True
        factor = np.where(edge, 1.0, 0.5)
        T, C, B = (data[:, i].astype(float) for i in range(3))
        tl = factor * (1 - T) * (1 + B) * (1 - C) * before + factor * (1 - T) * (1 - B) * \
            (1 + C) * after
        tr = factor * (1 - T) * (1 + B) * (1 + C) * before + factor * (1 - T) * (1 - B) * \
            (1 - C) * after
        slope_l, slope_r = np.where(tcb, tl, slope_l), np.where(tcb, tr, slope_r)
    if np.any(auto) and K > 2:
        inner = auto[1:-1]
        same = np.abs(slope_l[1:-1] + stored_r[1:-1]) <= 1e-4
        weights = (weight_l[1:-1], weight_r[1:-1])
        both = _auto_slopes(t, v, flags, stored_r[1:-1], *weights)
        left = np.where(same, both, _auto_slopes(t, v, flags, -slope_l[1:-1], *weights))
        slope_l[1:-1] = np.where(inner, left, slope_l[1:-1])
        slope_r[1:-1] = np.where(inner, both, slope_r[1:-1])
    if K > 1:
        for k, one_sided in ((0, secant[0]), (K - 1, secant[-1])):
            if auto[k]:
                progressive = flags[k] & _CLAMP_PROGRESSIVE or \
                    (flags[k] & _CLAMP and one_sided == 0)
                slope_l[k] = slope_r[k] = 0.0 if progressive else one_sided
    return slope_r, weight_r, slope_l, weight_l


def _evaluate(curve, ticks: np.ndarray) -> np.ndarray:
    """The curve's values at ``ticks`` ``(N,)``: each key holds its value at its time; between
    keys the earlier key's interpolation rules (constant: its value, or the next key's with
    "constant next"; linear; cubic: a Bezier segment whose tangents are the keys' slopes
    times their weights of the segment's length); outside the keys the first and last
    values hold."""
    times, values, flags, data = curve
    if len(times) == 0:
        return np.full(len(ticks), np.nan)
    out = np.empty(len(ticks))
    k = np.searchsorted(times, ticks, side="right") - 1
    before, after = k < 0, k >= len(times) - 1
    out[before] = values[0]
    out[after] = values[-1]
    inside = ~(before | after)
    if not np.any(inside):
        return out
    slope_r, weight_r, slope_l, weight_l = _tangents(times, values, flags, data)
    k = k[inside]
    t0, t1 = times[k], times[k + 1]
    v0, v1 = values[k], values[k + 1]
    u = (ticks[inside] - t0) / (t1 - t0)
    f = flags[k]
    dt = (t1 - t0) / FBX_TICKS_PER_SECOND
    value = v0 + (v1 - v0) * u                                     # linear
    constant = (f & _CONSTANT) != 0
    value[constant] = np.where(((f[constant] & _CONSTANT_NEXT) != 0) & (u[constant] > 0),
                               v1[constant], v0[constant])
    c = np.flatnonzero(~constant & ((f & _CUBIC) != 0))
    if len(c):
        w_r, w_l, d = weight_r[k[c]], weight_l[k[c] + 1], dt[c]
        value[c] = _bezier(u[c], v0[c], v0[c] + slope_r[k[c]] * d * w_r,
                           v1[c] - slope_l[k[c] + 1] * d * w_l, v1[c], w_r, 1 - w_l)
    out[inside] = value
    return out


def _bezier(u, p0, p1, p2, p3, x1, x2) -> np.ndarray:
    """A cubic Bezier's value where its time ``x(s)`` (control times 0, ``x1``, ``x2``, 1)
    equals ``u``: ``s = u`` for unweighted tangents (``x1 = 1/3``, ``x2 = 2/3``: ``x`` is
    then linear), else by bisection (``x`` increases for weights in (0, 1])."""
    s = np.array(u, dtype=float)
    weighted = np.flatnonzero(~(np.isclose(x1, 1 / 3) & np.isclose(x2, 2 / 3)))
    if len(weighted):
        uw, a, b = u[weighted], x1[weighted], x2[weighted]
        lo, hi = np.zeros_like(uw), np.ones_like(uw)
        for _ in range(50):
            mid = (lo + hi) / 2
            m = 1 - mid
            below = 3 * m * m * mid * a + 3 * m * mid * mid * b + mid ** 3 < uw
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        s[weighted] = (lo + hi) / 2
    m = 1 - s
    return m ** 3 * p0 + 3 * m * m * s * p1 + 3 * m * s * s * p2 + s ** 3 * p3


# =========================================================================== takes
@dataclass
class _Take:
    name: str
    node: Node
    channels: dict[tuple[int, str], list]   # (model, property) -> 3 curves or defaults
    start: int | None
    stop: int | None


def _takes(doc: _Doc, notes: list[str]) -> list[_Take]:
    """Every AnimationStack with its animated model properties (its first layer)."""
    takes = []
    layered = []
    for sid, node in doc.objects.items():
        if node.name != "AnimationStack":
            continue
        name, _ = _name_class(node.props[1] if len(node.props) > 1 else "")
        props = doc.props(node)
        start, stop = props.get("LocalStart"), props.get("LocalStop")
        layers = doc.linked(sid, "AnimationLayer", up=False)
        if len(layers) > 1:
            layered.append(name)
        channels: dict[tuple[int, str], list] = {}
        for layer in layers[:1]:
            for cn in doc.linked(layer, "AnimationCurveNode", up=False):
                defaults = _properties(doc.objects[cn])
                comps: list = [None, None, None]
                for c, comp in enumerate("XYZ"):
                    d = defaults.get(f"d|{comp}")
                    if d and isinstance(d[0], (int, float, np.number)):
                        comps[c] = float(d[0])
                for curve_id, prop in doc.children.get(cn, []):
                    if curve_id in doc.objects and doc.objects[curve_id].name == \
                            "AnimationCurve" and prop in ("d|X", "d|Y", "d|Z"):
                        comps["XYZ".index(prop[-1])] = _curve(doc, doc.objects[curve_id])
                for model, prop in doc.parents.get(cn, []):
                    if prop in _ANIMATED and model in doc.objects:
                        channels[(model, prop)] = comps
        takes.append(_Take(name or f"take {len(takes) + 1}", node, channels,
                           _tick(start), _tick(stop)))
    if layered:
        notes.append("only the first animation layer of a take is used (" +
                     ", ".join(layered) + " have several)")
    return takes


def _tick(values) -> int | None:
    """A ``KTime`` property's ticks (``None`` when absent, malformed or out of range)."""
    if values and _is_id(values[0]) and abs(int(values[0])) <= _MAX_TICKS:
        return int(values[0])
    return None


def _take_ticks(take: _Take, fps: float, doc: _Doc) -> np.ndarray:
    """The sample times [ticks] of a take: its local span (else its keys' span) at ``fps``."""
    keys = [c[0] for comps in take.channels.values() for c in comps
            if isinstance(c, tuple) and len(c[0])]
    first = min((int(k[0]) for k in keys), default=0)
    last = max((int(k[-1]) for k in keys), default=0)
    start = take.start if take.start is not None and (take.stop or 0) > take.start else first
    stop = take.stop if take.stop is not None and take.stop > start else max(last, start)
    count = int(round((stop - start) / FBX_TICKS_PER_SECOND * fps)) + 1
    if count > _MAX_FRAMES:
        raise doc.error(f"the take {take.name!r} lasts {count} frames at {fps:g} fps (at most "
                        f"{_MAX_FRAMES} are read)", take.node)
    return start + np.round(np.arange(count) * FBX_TICKS_PER_SECOND / fps).astype(np.int64)


# =========================================================================== the skeleton
@dataclass
class _Joints:
    models: list[int]            # model id per joint (-1: an added root)
    parents: np.ndarray
    names: list[str]


def _scene_parent(doc: _Doc, oid: int) -> int | None:
    """The model a model hangs under (``None`` under the scene root)."""
    ups = doc.linked(oid, "Model", up=True, prop=False)
    return ups[0] if ups else None


def _joint_tree(doc: _Doc, cluster_models: set[int], notes: list[str]) -> _Joints:
    models = {oid for oid, n in doc.objects.items() if n.name == "Model"}
    core = {m for m in models if doc.kind(m)[2] in _SKELETON_TYPES} | \
        (cluster_models & models)
    if not core:
        raise doc.error(_not_a_character(doc))
    members = set(core)
    for m in core:                                   # Null / LimbNode ancestors
        p = _scene_parent(doc, m)
        while p is not None and p not in members and doc.kind(p)[2] in _JOINT_TYPES:
            members.add(p)
            p = _scene_parent(doc, p)
    parent_of = {}
    for m in members:
        p = _scene_parent(doc, m)
        while p is not None and p not in members:
            p = _scene_parent(doc, p)
        parent_of[m] = p
    kids: dict[int | None, list[int]] = {}
    for m in sorted(members, key=lambda m: doc.objects[m].offset or 0):
        kids.setdefault(parent_of[m], []).append(m)
    order: list[int] = []
    tops = kids.get(None, [])
    stack = list(reversed(tops))
    while stack:
        m = stack.pop()
        order.append(m)
        stack.extend(reversed(kids.get(m, [])))
    if len(tops) > 1:
        notes.append(f"{len(tops)} separate joint trees joined under a new joint 'root' at the "
                     "origin")
        order = [-1] + order
    index = {m: j for j, m in enumerate(order)}
    parents = np.array([-1 if m < 0 else index.get(parent_of[m], 0 if len(tops) > 1 else -1)
                        for m in order], dtype=np.intp)
    names = _unique_names(["root" if m < 0 else (doc.kind(m)[1] or f"joint_{m}")
                           for m in order], notes)
    return _Joints(order, parents, names)


def _unique_names(names: list[str], notes: list[str]) -> list[str]:
    counts = Counter(names)
    taken = set(names)
    renamed = []
    out = []
    for nm in names:
        if counts[nm] > 1:
            k = 2
            while f"{nm}_{k}" in taken:
                k += 1
            taken.add(f"{nm}_{k}")
            renamed.append(f"{nm} -> {nm}_{k}")
            counts[nm] -= 1
            out.append(f"{nm}_{k}")
        else:
            out.append(nm)
    if renamed:
        notes.append("repeated joint names made unique: " + ", ".join(renamed))
    return out


def _not_a_character(doc: _Doc) -> str:
    """What a file without joints holds, in one sentence."""
    kinds: Counter = Counter()
    for oid, node in doc.objects.items():
        if node.name in ("Model", "Geometry"):
            kinds[(doc.kind(oid)[2] + " " + node.name.lower()).strip()] += 1
        elif node.name in ("AnimationStack", "Material", "Texture", "Video", "Deformer",
                           "NodeAttribute", "Pose", "Constraint"):
            kinds[node.name] += 1
    held = ", ".join(f"{n} {k}" if n == 1 else f"{n} {k[:-8]}geometries" if
                     k.endswith("geometry") else f"{n} {k}s"
                     for k, n in kinds.most_common(6)) or "no objects"
    if not any(node.name == "Model" for node in doc.objects.values()):
        held += " and no models"
    return (f"not a character: no skeleton (no LimbNode, Root or skinned models); the file "
            f"holds {held}")


# =========================================================================== evaluation
class _Evaluator:
    """World matrices (file space) of the joints and the models above them."""

    def __init__(self, doc: _Doc, joints: _Joints):
        self.doc = doc
        self.models: dict[int, _Model] = {}
        chain: list[int] = []
        seen: set[int] = set()
        for m in joints.models:
            path = []
            while m is not None and m >= 0 and m not in seen:
                seen.add(m)
                path.append(m)
                m = _scene_parent(doc, m)
            chain.extend(reversed(path))
        self.order = self._parents_first(chain)
        for m in self.order:
            self.models[m] = _model(doc, m)

    def _parents_first(self, nodes: list[int]) -> list[int]:
        done: list[int] = []
        placed: set[int] = set()
        for m in nodes:
            path = []
            while m is not None and m not in placed:
                if m in path:
                    raise self.doc.error("models whose parents form a loop", self.doc.objects[m])
                path.append(m)
                m = _scene_parent(self.doc, m)
            for p in reversed(path):
                placed.add(p)
                done.append(p)
        return done

    def worlds(self, take: _Take | None, ticks: np.ndarray | None) -> dict[int, np.ndarray]:
        """``{model: (N, 4, 4)}`` world matrices at ``ticks`` (one rest frame without a
        take)."""
        n = 1 if ticks is None else len(ticks)
        out: dict[int, np.ndarray] = {}
        scaling: dict[int, np.ndarray] = {}
        for m in self.order:
            model = self.models[m]
            trs = []
            for prop, own in zip(_ANIMATED, (model.translation, model.rotation,
                                             model.scaling)):
                comps = take.channels.get((m, prop)) if take is not None else None
                trs.append(None if comps is None else _sample(comps, own, ticks))
            local = np.broadcast_to(model.local(*trs), (n, 4, 4))
            scaling[m] = np.broadcast_to(model.scaling if trs[2] is None else trs[2], (n, 3))
            p = _scene_parent(self.doc, m)
            out[m] = _world(model, local, out.get(p), scaling.get(p))
        return out


def _sample(comps: list, own: np.ndarray, ticks: np.ndarray) -> np.ndarray:
    """``(N, 3)`` an animated property at ``ticks``: curves, else the curve node's default,
    else the model's own value."""
    out = np.empty((len(ticks), 3))
    for c in range(3):
        value = comps[c]
        if isinstance(value, tuple):
            v = _evaluate(value, ticks)
            out[:, c] = np.where(np.isnan(v), own[c], v)
        else:
            out[:, c] = own[c] if value is None else value
    return out


# =========================================================================== bind pose
def _clusters(doc: _Doc):
    """Per Skin deformer: its geometry, name and clusters ``(model, cluster node)``."""
    skins = []
    for oid, node in doc.objects.items():
        if node.name != "Deformer" or doc.kind(oid)[2] != "Skin":
            continue
        geometry = doc.linked(oid, "Geometry", up=True)
        clusters = []
        for cid in doc.linked(oid, "Deformer", up=False):
            if doc.kind(cid)[2] != "Cluster":
                continue
            linked = doc.linked(cid, "Model", up=False)
            if linked:
                clusters.append((linked[0], doc.objects[cid]))
        if geometry and clusters:
            skins.append((geometry[0], doc.kind(oid)[1] or f"skin_{oid}", clusters))
    return skins


def _inverse(doc: _Doc, m: np.ndarray, what: str) -> np.ndarray:
    """The inverse of a 4x4 transform of ``what`` (a joint or a mesh), refusing one that
    has none (a zero scale) or is not finite."""
    linear = m[:3, :3]
    if not np.all(np.isfinite(m)) or not abs(np.linalg.det(linear)) > 1e-12 * max(
            1.0, float(np.abs(linear).max()) ** 3):
        raise doc.error(f"the transform of {what} has a zero scale or is not finite, so it "
                        "cannot be inverted")
    return np.linalg.inv(m)


def _bind_pose_matrices(doc: _Doc) -> dict[int, np.ndarray]:
    """World matrices of the ``Pose``/``BindPose`` objects (file space)."""
    out: dict[int, np.ndarray] = {}
    for oid, node in doc.objects.items():
        if node.name != "Pose" or doc.kind(oid)[2] != "BindPose":
            continue
        for pn in node.find_all("PoseNode"):
            ref = pn.find("Node")
            matrix = _matrix16(doc, pn, "Matrix")
            if ref is not None and ref.props and _is_id(ref.props[0]) and matrix is not None:
                out.setdefault(int(ref.props[0]), matrix)
    return out


def _bind_matrices(doc: _Doc, joints: _Joints, ev: _Evaluator, links: dict[int, np.ndarray],
                   notes: list[str]) -> np.ndarray:
    """``(J, 4, 4)`` file-space bind matrices (see the module notes)."""
    poses = _bind_pose_matrices(doc)
    rest = ev.worlds(None, None)
    J = len(joints.models)
    bind = np.tile(np.eye(4), (J, 1, 1))
    from_rest = 0
    for j, m in enumerate(joints.models):
        if m < 0:
            continue
        if m in links:
            bind[j] = links[m]
        elif m in poses:
            bind[j] = poses[m]
        else:
            p = joints.parents[j]
            if p >= 0 and joints.models[p] >= 0:
                pm = joints.models[p]
                bind[j] = bind[p] @ _inverse(doc, rest[pm][0], joints.names[p]) @ rest[m][0]
            else:
                bind[j] = rest[m][0]
            from_rest += 1
    if links and from_rest:
        notes.append(f"{_plural(from_rest, 'joint')} outside the skin and the bind pose placed "
                     "by their rest transform")
    return bind


# =========================================================================== meshes
def _polygons(doc: _Doc, geometry: Node) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3), triangles (T, 3))`` of a Mesh geometry (polygons fanned)."""
    flat = _array(doc, geometry, "Vertices")
    if len(flat) % 3:
        raise doc.error(f"{len(flat)} vertex coordinates (not a whole number of points)",
                        geometry)
    vertices = flat.reshape(-1, 3)
    index = _array(doc, geometry, "PolygonVertexIndex", integer=True)
    ends = index < 0
    corners = np.where(ends, ~index, index)
    if len(index) and (not ends[-1] or corners.max() >= len(vertices) or corners.min() < 0):
        raise doc.error("PolygonVertexIndex names vertices that do not exist or does not end "
                        "its last polygon", geometry)
    starts = np.concatenate([[0], np.flatnonzero(ends)[:-1] + 1]) if len(index) else \
        np.zeros(0, dtype=np.int64)
    sizes = np.flatnonzero(ends) + 1 - starts if len(index) else starts
    tris = []
    for k in range(1, int(sizes.max()) - 1 if len(sizes) else 0):
        has = sizes > k + 1
        first = starts[has]
        tris.append(np.stack([corners[first], corners[first + k], corners[first + k + 1]], 1))
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    return vertices, triangles


def _normals(doc: _Doc, geometry: Node, index: np.ndarray, V: int) -> np.ndarray | None:
    """Per-vertex normals ``(V, 3)`` of the first normal layer (polygon-vertex normals
    averaged per vertex), or ``None``."""
    layer = geometry.find("LayerElementNormal")
    if layer is None:
        return None
    normals = _array(doc, layer, "Normals", required=False)
    if normals is None or len(normals) % 3:
        return None
    normals = normals.reshape(-1, 3)
    mapping = layer.find("MappingInformationType")
    reference = layer.find("ReferenceInformationType")
    mapping = mapping.props[0] if mapping is not None and mapping.props else ""
    reference = reference.props[0] if reference is not None and reference.props else "Direct"
    if reference == "IndexToDirect":
        idx = _array(doc, layer, "NormalsIndex", integer=True, required=False)
        if idx is None or (len(idx) and (idx.max() >= len(normals) or idx.min() < 0)):
            return None
        normals = normals[idx]
    corners = np.where(index < 0, ~index, index)
    if mapping in ("ByVertice", "ByVertex", "ByControlPoint") and len(normals) == V:
        per_vertex = normals
    elif mapping == "ByPolygonVertex" and len(normals) == len(corners):
        per_vertex = np.zeros((V, 3))
        np.add.at(per_vertex, corners, normals)
    else:
        return None
    length = np.linalg.norm(per_vertex, axis=1, keepdims=True)
    return per_vertex / np.where(length > 1e-12, length, 1.0)


def _influences(doc: _Doc, clusters, index_of: dict[int, int], V: int):
    """``(joints (V, K), weights (V, K))`` from a skin's clusters (rows normalised; a vertex
    no cluster moves is bound to the first cluster's joint), and how many were normalised."""
    rows: list[list[tuple[int, float]]] = [[] for _ in range(V)]
    for model, node in clusters:
        idx = _array(doc, node, "Indexes", integer=True, required=False)
        w = _array(doc, node, "Weights", required=False)
        if idx is None or w is None:
            continue
        if len(idx) != len(w):
            raise doc.error(f"{len(idx)} indexes but {len(w)} weights", node)
        if len(idx) and (idx.min() < 0 or idx.max() >= V):
            raise doc.error(f"vertex index {int(idx.max())} but the mesh has {V} vertices",
                            node)
        j = index_of[model]
        for v, weight in zip(idx.tolist(), w.tolist()):
            if weight > 0:
                rows[v].append((j, weight))
    K = max(1, max(len(r) for r in rows)) if rows else 1
    joints = np.zeros((V, K), dtype=np.intp)
    weights = np.zeros((V, K))
    fallback = index_of[clusters[0][0]]
    unbound = 0
    for v, r in enumerate(rows):
        if not r:
            joints[v, 0], weights[v, 0] = fallback, 1.0
            unbound += 1
            continue
        for k, (j, weight) in enumerate(r):
            joints[v, k], weights[v, k] = j, weight
    weights /= weights.sum(axis=1, keepdims=True)
    return joints, weights, unbound


def _meshes(doc: _Doc, joints: _Joints, A, s, notes: list[str],
            bind_file: np.ndarray) -> list[Mesh]:
    """The skinned meshes in the bind pose (engine space), then the rigid parts: meshes
    without a skin whose model hangs under a joint (a game rig's armour plates, the robot's
    limbs as Blender's FBX exporter writes them), bound wholly to that joint and placed by
    their models' transforms below it (``bind_file``: the joints' file-space bind
    matrices)."""
    index_of = {m: j for j, m in enumerate(joints.models) if m >= 0}
    out = []
    unbound_total = 0
    for geometry_id, skin_name, clusters in _clusters(doc):
        geometry = doc.objects[geometry_id]
        if doc.kind(geometry_id)[2] != "Mesh":
            continue
        clusters = [c for c in clusters if c[0] in index_of]
        if not clusters:
            continue
        vertices, triangles = _polygons(doc, geometry)
        link = _matrix16(doc, clusters[0][1], "TransformLink")
        transform = _matrix16(doc, clusters[0][1], "Transform")
        frame = (link if link is not None else np.eye(4)) @ \
            (transform if transform is not None else np.eye(4))
        positions, normals = _placed(doc, geometry, vertices, _to_engine(frame, A, s), A, s,
                                     f"the mesh {doc.kind(geometry_id)[1]!r}")
        jj, ww, unbound = _influences(doc, clusters, index_of, len(vertices))
        unbound_total += unbound
        owner = doc.linked(geometry_id, "Model", up=True)
        name = doc.kind(owner[0])[1] if owner else doc.kind(geometry_id)[1] or skin_name
        out.append(Mesh(name=name or skin_name, positions=_frozen(positions),
                        normals=None if normals is None else _frozen(normals),
                        triangles=_frozen(triangles), joints=_frozen(jj),
                        weights=_frozen(ww), skin=len(out), node=int(owner[0]) if owner
                        else int(geometry_id)))
    if unbound_total:
        what = "1 vertex" if unbound_total == 1 else f"{unbound_total} vertices"
        notes.append(f"{what} no cluster weighs bound to their skin's first joint")
    skinned = {m.node for m in out}
    loose = rigid = 0
    for oid, node in doc.objects.items():
        if node.name != "Model" or doc.kind(oid)[2] != "Mesh" or oid in skinned:
            continue
        part = _rigid_part(doc, oid, index_of, A, s, bind_file)
        if part is None:
            loose += 1
        else:
            out.append(part)
            rigid += 1
    if rigid:
        notes.append(f"{rigid} rigid mesh part{'s' if rigid != 1 else ''} under joint models "
                     "bound to their joints")
    if loose:
        notes.append(f"{loose} mesh{'es' if loose != 1 else ''} on no joint of the skeleton "
                     "left out")
    return out


def _placed(doc: _Doc, geometry: Node, vertices: np.ndarray, frame: np.ndarray, A, s,
            what: str):
    """A geometry's ``vertices`` (file units and axes) and its normals (``None`` where it has
    none) placed by ``frame`` (engine space: the vertices are scaled into metres first)."""
    positions = (A @ (vertices.T * s)).T @ frame[:3, :3].T + frame[:3, 3]
    index = _array(doc, geometry, "PolygonVertexIndex", integer=True)
    normals = _normals(doc, geometry, index, len(vertices))
    if normals is not None:
        normals = (A @ normals.T).T @ _inverse(doc, frame, what)[:3, :3]
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = normals / np.where(length > 1e-12, length, 1.0)
    return positions, normals


def _rigid_part(doc: _Doc, oid: int, index_of: dict[int, int], A, s,
                bind_file: np.ndarray) -> Mesh | None:
    """The mesh of model ``oid`` (no skin) bound wholly to the joint its model hangs under,
    in the bind pose (engine space); ``None`` where it hangs under no joint or has no
    polygons. The models between it and the joint are placed by their own transforms (their
    Lcl values; an InheritType of 2 between them is not applied), and the mesh's
    GeometricTranslation, GeometricRotation and GeometricScaling after them."""
    chain = np.eye(4)
    m, seen = oid, set()
    while m not in index_of:
        if m in seen:
            raise doc.error("models whose parents form a loop", doc.objects[m])
        seen.add(m)
        chain = _model(doc, m).local()[0] @ chain
        m = _scene_parent(doc, m)
        if m is None:
            return None
    geometry = [g for g in doc.linked(oid, "Geometry", up=False)
                if doc.kind(g)[2] == "Mesh"]
    if not geometry:
        return None
    p = doc.props(doc.objects[oid])
    shift = np.eye(4)
    shift[:3, :3] = _euler(_vector(p, "GeometricRotation", (0, 0, 0))[None], "xyz")[0] * \
        _vector(p, "GeometricScaling", (1, 1, 1))
    shift[:3, 3] = _vector(p, "GeometricTranslation", (0, 0, 0))
    j = index_of[m]
    name = doc.kind(oid)[1] or f"mesh_{oid}"
    node = doc.objects[geometry[0]]
    vertices, triangles = _polygons(doc, node)
    if not len(triangles):
        return None
    positions, normals = _placed(doc, node, vertices,
                                 _to_engine(bind_file[j] @ chain @ shift, A, s), A, s,
                                 f"the mesh {name!r}")
    if not np.all(np.isfinite(positions)):
        raise doc.error(f"the mesh {name!r} is not finite where its joint's bind pose puts it")
    V = len(vertices)
    return Mesh(name=name, positions=_frozen(positions),
                normals=None if normals is None else _frozen(normals),
                triangles=_frozen(triangles), joints=_frozen(np.full((V, 1), j, dtype=np.intp)),
                weights=_frozen(np.ones((V, 1))), skin=None, node=int(oid))


# =========================================================================== the character
def _engine_pose(doc, name, worlds, joints, A, s, bind_rot):
    """A :class:`_Pose` of the joints from file-space world matrices (``None`` when a joint is
    scaled non-uniformly)."""
    any_world = next(iter(worlds.values()))
    n = any_world.shape[0]
    G = np.array([worlds[m] if m >= 0 else np.broadcast_to(np.eye(4), (n, 4, 4))
                  for m in joints.models]).transpose(1, 0, 2, 3)
    return _pose_from_world(_to_engine(G, A, s), bind_rot, joints.parents, name)


def _channels(parents: np.ndarray, offsets: np.ndarray, size: float, poses) -> tuple:
    """Per joint, its BVH channels: rotations, and positions for the root and every joint whose
    local translation strays from its offset in one of ``poses``."""
    tol = _MOVE_TOL * max(size, 1e-9)
    moving = np.zeros(len(parents), dtype=bool)
    moving[0] = True
    for pose in poses:
        dev = np.linalg.norm(_local_translations(pose, parents) - offsets, axis=-1).max(axis=0)
        moving |= dev > tol
    return tuple(POSITION_LAYOUT + ROTATION_LAYOUT if m else ROTATION_LAYOUT for m in moving)


def _build(doc: _Doc, name: str, fps: float | None, notes: list[str],
           up_axis: str | None = None) -> Character:
    A, s, reason = _axis_frame(doc)
    if up_axis is not None and up_axis != "+Y":
        # the figure stands along ``up_axis`` once the file's axis settings are applied
        try:
            A = up_axis_rotation(up_axis) @ A
        except ValueError as exc:
            raise FBXError(str(exc), doc.path) from None
        reason += f"; read with {up_axis} up as given (turned onto +Y)"
    fps = _frame_rate(doc) if fps is None else fps
    skins = _clusters(doc)
    links: dict[int, np.ndarray] = {}
    for _, _, clusters in skins:
        for model, node in clusters:
            link = _matrix16(doc, node, "TransformLink")
            if link is not None:
                links.setdefault(model, link)
    joints = _joint_tree(doc, set(links), notes)
    ev = _Evaluator(doc, joints)
    bind_file = _bind_matrices(doc, joints, ev, links, notes)
    bind = _to_engine(bind_file, A, s)
    if not np.all(np.isfinite(bind)):
        raise doc.error("the bind pose is not finite (a zero scale on a joint?)")
    rot, sig, det = _polar(bind[:, :3, :3])
    spread = sig.max(axis=-1) / np.maximum(sig.min(axis=-1), 1e-300) - 1.0
    if np.any(spread > _SCALE_TOL) or np.any(det <= 0):
        j = int(np.flatnonzero((spread > _SCALE_TOL) | (det <= 0))[0])
        raise doc.error(f"the bind pose of joint {joints.names[j]!r} is scaled non-uniformly "
                        "or mirrored (not supported)")
    bind_pos = bind[:, :3, 3].copy()
    offsets = bind_pos.copy()
    offsets[1:] -= bind_pos[joints.parents[1:]]
    size = float(np.ptp(bind_pos, axis=0).max()) if len(bind_pos) > 1 else 1.0

    rest = _engine_pose(doc, "rest pose", ev.worlds(None, None), joints, A, s, rot)
    poses = []
    for take in _takes(doc, notes):
        if not any(m in ev.models for m, _ in take.channels):
            notes.append(f"take {take.name!r} animates no joint (left out)")
            continue
        pose = _engine_pose(doc, take.name, ev.worlds(take, _take_ticks(take, fps, doc)),
                            joints, A, s, rot)
        if pose is None:
            notes.append(f"take {take.name!r} scales a joint non-uniformly (or beyond finite "
                         "numbers); it was left out")
            continue
        poses.append(pose)
    if rest is None:
        raise doc.error("the rest pose scales a joint non-uniformly (not supported)")
    source = SourceFrame(units="m", scale=1.0, up_axis=up_axis or "+Y", detected=False,
                         reason=reason)
    skeleton = Skeleton(names=joints.names, parents=joints.parents, offsets=offsets,
                        channels=_channels(joints.parents, offsets, size, [rest] + poses),
                        source=source)
    motions = tuple(_pose_motion(p, skeleton, joints.parents, 1.0 / fps) for p in poses)
    doubted = with_lying_doubt(skeleton, "rest pose", motions)
    if doubted is not skeleton:
        skeleton = doubted
        motions = tuple(m.replace(skeleton=skeleton) for m in motions)
    node_pose = _pose_motion(rest, skeleton, joints.parents, 1.0 / fps).replace(
        name=f"{name} (rest pose)")
    meshes = _meshes(doc, joints, A, s, notes, bind_file)
    J = len(joints.models)
    node_t = np.zeros((J, 3))
    node_q = np.tile([0.0, 0.0, 0.0, 1.0], (J, 1))
    node_s = np.ones((J, 3))
    for j, m in enumerate(joints.models):
        if m >= 0:
            model = ev.models[m]
            turn, _, _ = _polar(model.local()[:, :3, :3])
            node_t[j] = model.translation
            node_q[j] = _matrix_to_quat(turn)[0]
            node_s[j] = model.scaling
    skin_maps = []
    skin_names = []
    index_of = {m: j for j, m in enumerate(joints.models)}
    for _, skin_name, clusters in skins:
        skin_maps.append(_frozen(np.array([index_of[m] for m, _ in clusters if m in index_of],
                                          dtype=np.intp)))
        skin_names.append(skin_name)
    return Character(
        name=name, skeleton=skeleton, meshes=tuple(meshes), motions=motions,
        bind_rotations=_frozen(_matrix_to_quat(rot)), bind_scales=_frozen(sig.mean(axis=-1)),
        node_translations=_frozen(node_t), node_rotations=_frozen(node_q),
        node_scales=_frozen(node_s), node_indices=_frozen(np.array(
            [m for m in joints.models], dtype=np.int64)),
        skin_joints=tuple(skin_maps), skin_frames=_frozen(np.tile(np.eye(4),
                                                                  (len(skins), 1, 1))),
        skin_names=tuple(skin_names), skins=tuple(range(len(skins))), node_pose=node_pose,
        fps=float(fps), path=doc.path, notes=tuple(notes))


def read_fbx(path: str | os.PathLike, *, fps: float | None = None,
             up_axis: str | None = None) -> Character:
    """Read an FBX 7.x character (binary or ASCII) with every take, or the skeleton of an
    ASCII FBX 6.x file (see the module notes and :mod:`.legacy`).

    Args:
        fps: the rate takes are sampled at; by default the file's own (``TimeMode``).
        up_axis: the axis the figure stands along once the file's axis settings are
            applied (one of :data:`engine.units.AXES`), for a file whose settings say
            nothing true: the whole scene is turned onto +Y. By default +Y (the settings
            are trusted).

    Raises:
        FBXError: for a malformed file, binary FBX 6 and FBX 5 and older, or a file that
            holds no skeleton
            (saying what it holds).
    """
    path = os.fspath(path)
    with reading(path, FBXError, "an FBX file"):
        data = Path(path).read_bytes()
    root = parse_fbx(data, path)
    notes: list[str] = []
    if int(root.props[0]) < 7000:
        root, notes = from_fbx6(root)
    doc = _Doc(root, path, ascii_form=not is_binary_fbx(data[:32]))
    return _build(doc, Path(path).stem, fps, notes, up_axis)


def take_motion(character: Character, take: str | None = None) -> Motion:
    """The take ``take`` of an FBX character (its full name, or the part after its last
    ``|``, as in Blender's ``Armature|Walk``), by default the first.

    Raises:
        FBXError: for a file without a take that moves a joint, or an unknown name (the
            message lists the takes).
    """
    takes = character.motions
    known = ", ".join(repr(m.name) for m in takes)
    if not takes:
        raise FBXError("the file holds no take that moves a joint (a character only: use it as "
                       "the target)", character.path)
    if take is None:
        return takes[0]
    exact = [m for m in takes if m.name == take]
    short = [m for m in takes if m.name.rsplit("|", 1)[-1] == take]
    found = exact or short
    if len(found) != 1:
        what = "several takes are" if found else "no take is"
        raise FBXError(f"{what} named {take!r} (takes: {known})", character.path)
    return found[0]
