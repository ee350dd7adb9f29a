"""Writing a motion (and the character it is on) as binary FBX 7.4.

:func:`write_fbx` builds the document tree (:class:`~.nodes.Node`) the FBX SDK writes for an
animated, skinned skeleton and encodes it with :func:`~.encode.encode_binary`:

``FBXHeaderExtension``, ``FileId``, ``CreationTime``, ``Creator``
    the header; ``CreationTime`` and ``FileId`` are the consistent pair of :mod:`.encode`, and
    the header's time stamp is the same instant, so one motion always gives the same bytes.
``GlobalSettings``
    +Y up, +Z front, +X right (right-handed, the engine's own axes: nothing is converted),
    ``UnitScaleFactor`` 1: **centimetres**. Every length is written in centimetres (metres times
    100) because that is what Maya, MotionBuilder and Mixamo write and Unreal works in; Unity
    turns a centimetre file into metres by its file scale of 0.01 and Blender's importer by an
    object scale of 0.01, so world positions come out right everywhere. (A metre file with
    ``UnitScaleFactor`` 100, Blender's own default, makes Unreal put a 100x scale on the
    skeleton's root.) ``TimeMode`` is the motion's rate when FBX names it (24, 25, 30, 60,
    120, ... frames per second, NTSC's 29.97 etc.; a rate within 1e-4 of one of them is
    taken as it, see :func:`frame_rate`), else ``CustomFrameRate``.
``Documents``, ``References``
    one scene document whose active animation stack is the motion.
``Definitions``
    the count of every object type and the SDK's property templates (the defaults of the
    properties an object does not write).
``Objects``
    per joint a ``Model`` of class ``LimbNode`` and its ``NodeAttribute`` (``Skeleton``); the
    joint's translation and rotation at rest as ``Lcl Translation`` / ``Lcl Rotation`` (Euler
    degrees in its own rotation order, ``RotationOrder``, with ``RotationActive`` on, without
    which readers ignore the order). The skeleton's root joint is the top ``LimbNode``, under
    the scene root, as Maya and Mixamo write skeletons: the engine's skeleton always has one
    root, so no ``Null`` above it is needed. A ``Pose`` of type ``BindPose`` gives every
    joint's (and mesh's) world matrix in the bind pose. The motion is one ``AnimationStack``
    with one ``AnimationLayer``; every joint has a ``T`` and an ``R`` ``AnimationCurveNode``
    with one ``AnimationCurve`` per axis, one linear key per frame at ``k / fps`` seconds.
    With a character, each skinned mesh is a ``Model`` of class ``Mesh`` with its ``Geometry``
    (vertices in the bind pose, triangles, normals by vertex), a ``Skin`` deformer and one
    ``Cluster`` per joint that weighs on it (vertex indices, weights, ``TransformLink``: the
    joint's world matrix at bind; ``Transform``: the mesh's world matrix at bind in the joint's
    frame).
``Connections``, ``Takes``
    the object graph (``OO`` object to parent, ``OP`` curve node to property) and the take.

Joint axes: a glTF character's joints keep their own axes (:attr:`Character.bind_rotations`),
as :func:`~engine.formats.gltf.write_gltf` keeps them, so a tool shows the bones as the
character's author oriented them; without a character every joint's axes are the world's at
rest (a BVH skeleton's).
"""
from __future__ import annotations

import os

import numpy as np

from ...errors import ExportError
from ...fileio import atomic_write
from ...motion import Motion
from ...quaternions import qconj, qmul, qrot, to_matrix
from ...rotations import quat_to_euler
from ..gltf import Character, _rest_positions, check_fits
from .encode import CREATION_TIME, FILE_ID, encode_binary
from .nodes import FBX_TICKS_PER_SECOND, Node

__all__ = ["write_fbx", "format_fbx", "fbx_document", "CENTIMETRES_PER_METRE", "FBX_VERSION",
           "TIME_MODES", "TIME_MODE_CUSTOM", "rotation_order", "frame_rate"]

#: the binary version written (FBX 7.4, the format of the 2014-2015 SDKs, which every later
#: SDK and the tools built on them read)
FBX_VERSION = 7400
#: lengths are written in centimetres (``UnitScaleFactor`` 1)
CENTIMETRES_PER_METRE = 100.0
#: FBX ``TimeMode`` per frame rate it names; any other rate is custom (14)
TIME_MODES = {120.0: 1, 100.0: 2, 60.0: 3, 50.0: 4, 48.0: 5, 30.0: 6, 30000 / 1001: 9,
              25.0: 10, 24.0: 11, 1000.0: 12, 24000 / 1001: 13, 96.0: 15, 72.0: 16,
              60000 / 1001: 17, 120000 / 1001: 18}
TIME_MODE_CUSTOM = 14
#: a motion's rate this close (relatively) to one FBX names is that rate
_SAME_RATE = 1e-4
#: FBX ``RotationOrder`` values: eEulerXYZ (X applied first, R = Rz Ry Rx) = 0, ...
_FBX_ORDERS = ("XYZ", "XZY", "YZX", "YXZ", "ZXY", "ZYX")
#: the intrinsic order of a joint without three rotation channels (FBX's default, XYZ)
_DEFAULT_ORDER = "ZYX"
#: linear interpolation (0x4); the tangent bits are the SDK's default auto-clamped ones
_KEY_FLAGS = 0x4 | 0x100 | 0x2000 | 0x4000
#: right and next-left slopes 0, both tangent weights 1/3 (0x0D05 twice), velocities 0
_KEY_DATA = np.array([0, 0, 0x0D050D05, 0], dtype=np.int32).view(np.float32)
_CREATOR = "Motion Composer"


# --------------------------------------------------------------------------- small builders
def _name(name: str, cls: str) -> str:
    """An object's name as binary FBX writes it: ``Name\\x00\\x01Class``."""
    return f"{name}\x00\x01{cls}"


def _p(name: str, kind: str, label: str, flags: str, *values) -> Node:
    """One ``P`` property record of a ``Properties70`` block."""
    return Node("P", [name, kind, label, flags, *values])


def _int(name: str, value: int) -> Node:
    return _p(name, "int", "Integer", "", np.int32(value))


def _enum(name: str, value: int) -> Node:
    return _p(name, "enum", "", "", np.int32(value))


def _bool(name: str, value: bool) -> Node:
    return _p(name, "bool", "", "", np.int32(bool(value)))


def _double(name: str, value: float) -> Node:
    return _p(name, "double", "Number", "", float(value))


def _vector(name: str, xyz, kind: str = "Vector3D", label: str = "Vector",
            flags: str = "") -> Node:
    return _p(name, kind, label, flags, *(float(v) for v in xyz))


def _time(name: str, ticks: int) -> Node:
    return _p(name, "KTime", "Time", "", int(ticks))


def _string(name: str, value: str) -> Node:
    return _p(name, "KString", "", "", value)


def _props(*records: Node) -> Node:
    return Node("Properties70", [], list(records))


def _matrix(m: np.ndarray) -> np.ndarray:
    """A 4x4 matrix (column vectors) as FBX stores it: 16 doubles, column by column."""
    return np.ascontiguousarray(np.asarray(m, dtype=np.float64).T).reshape(16)


class _Ids:
    """Object ids, deterministic: the same document always gets the same ids."""

    def __init__(self, start: int = 1_000_000):
        self.next = start

    def __call__(self) -> int:
        self.next += 1
        return self.next


def rotation_order(order: str) -> tuple[str, int]:
    """A joint's intrinsic rotation order (``"ZXY"``: R = Rz Rx Ry, the BVH channel order)
    completed to three axes, and the FBX ``RotationOrder`` that means the same rotation (the
    reverse sequence: FBX names the axis applied first, ``eEulerYXZ`` = 3 here). A joint
    without three rotation channels gets FBX's default, XYZ."""
    seq = order.upper() if len(order) == 3 else _DEFAULT_ORDER
    return seq, _FBX_ORDERS.index(seq[::-1])


def _euler_xyz(quats: np.ndarray, seq: str, *, unwrap: bool) -> np.ndarray:
    """``(F, 3)`` Euler degrees about X, Y, Z (FBX's ``Lcl Rotation`` layout) of ``(F, 4)``
    quaternions in intrinsic order ``seq``."""
    angles = quat_to_euler(quats, seq, unwrap=unwrap)
    out = np.empty_like(angles)
    for k, axis in enumerate(seq):
        out[:, "XYZ".index(axis)] = angles[:, k]
    return out


def frame_rate(fps: float) -> tuple[float, int]:
    """The rate keys are written at for a motion at ``fps`` frames per second, and its
    ``TimeMode``: a rate FBX names when ``fps`` is within 1e-4 (relatively) of it (a BVH's
    rounded frame time 0.0083333 s is 120 fps, as :meth:`Motion.resampled` takes it), else
    ``fps`` itself with the custom mode."""
    for rate, mode in TIME_MODES.items():
        if abs(fps - rate) <= _SAME_RATE * rate:
            return rate, mode
    return float(fps), TIME_MODE_CUSTOM


# --------------------------------------------------------------------------- the sections
def _header() -> list[Node]:
    date, clock = CREATION_TIME.split(" ")
    year, month, day = (int(x) for x in date.split("-"))
    hour, minute, second, milli = (int(x) for x in clock.split(":"))
    stamp = Node("CreationTimeStamp", [], [
        Node("Version", [np.int32(1000)]), Node("Year", [np.int32(year)]),
        Node("Month", [np.int32(month)]), Node("Day", [np.int32(day)]),
        Node("Hour", [np.int32(hour)]), Node("Minute", [np.int32(minute)]),
        Node("Second", [np.int32(second)]), Node("Millisecond", [np.int32(milli)])])
    meta = Node("MetaData", [], [Node("Version", [np.int32(100)])] +
                [Node(k, [""]) for k in ("Title", "Subject", "Author", "Keywords", "Revision",
                                         "Comment")])
    app = []
    for when in ("Original", "LastSaved"):
        app += [_p(when, "Compound", "", ""),
                _string(f"{when}|ApplicationVendor", "Motion Composer"),
                _string(f"{when}|ApplicationName", "Motion Composer")]
    info = Node("SceneInfo", [_name("GlobalInfo", "SceneInfo"), "UserData"], [
        Node("Type", ["UserData"]), Node("Version", [np.int32(100)]), meta, _props(*app)])
    extension = Node("FBXHeaderExtension", [], [
        Node("FBXHeaderVersion", [np.int32(1003)]), Node("FBXVersion", [np.int32(FBX_VERSION)]),
        Node("EncryptionType", [np.int32(0)]), stamp, Node("Creator", [_CREATOR]), info])
    return [extension, Node("FileId", [FILE_ID]), Node("CreationTime", [CREATION_TIME]),
            Node("Creator", [_CREATOR])]


def _global_settings(fps: float, stop: int) -> Node:
    rate, mode = frame_rate(fps)
    custom = rate if mode == TIME_MODE_CUSTOM else -1.0
    return Node("GlobalSettings", [], [Node("Version", [np.int32(1000)]), _props(
        _int("UpAxis", 1), _int("UpAxisSign", 1), _int("FrontAxis", 2), _int("FrontAxisSign", 1),
        _int("CoordAxis", 0), _int("CoordAxisSign", 1), _int("OriginalUpAxis", 1),
        _int("OriginalUpAxisSign", 1), _double("UnitScaleFactor", 1.0),
        _double("OriginalUnitScaleFactor", 1.0), _vector("AmbientColor", (0, 0, 0), "ColorRGB",
                                                         "Color"),
        _string("DefaultCamera", "Producer Perspective"), _enum("TimeMode", mode),
        _enum("TimeProtocol", 2), _enum("SnapOnFrameMode", 0), _time("TimeSpanStart", 0),
        _time("TimeSpanStop", stop), _double("CustomFrameRate", custom))])


def _documents(ids: _Ids, take: str) -> list[Node]:
    document = Node("Document", [ids(), "Scene", "Scene"], [
        _props(_p("SourceObject", "object", "", ""), _string("ActiveAnimStackName", take)),
        Node("RootNode", [0])])
    return [Node("Documents", [], [Node("Count", [np.int32(1)]), document]),
            Node("References")]


def _templates() -> dict[str, tuple[str, list[Node]]]:
    """The SDK's property templates of the object types written: type -> (template name,
    its properties)."""
    node = [
        _enum("QuaternionInterpolate", 0), _vector("RotationOffset", (0, 0, 0)),
        _vector("RotationPivot", (0, 0, 0)), _vector("ScalingOffset", (0, 0, 0)),
        _vector("ScalingPivot", (0, 0, 0)), _bool("TranslationActive", False),
        _enum("RotationOrder", 0), _bool("RotationSpaceForLimitOnly", False),
        _vector("PreRotation", (0, 0, 0)), _vector("PostRotation", (0, 0, 0)),
        _bool("RotationActive", False), _enum("InheritType", 0),
        _bool("ScalingActive", False), _vector("GeometricTranslation", (0, 0, 0)),
        _vector("GeometricRotation", (0, 0, 0)), _vector("GeometricScaling", (1, 1, 1)),
        _bool("Show", True), _int("DefaultAttributeIndex", -1), _bool("Freeze", False),
        _bool("LODBox", False),
        _vector("Lcl Translation", (0, 0, 0), "Lcl Translation", "", "A"),
        _vector("Lcl Rotation", (0, 0, 0), "Lcl Rotation", "", "A"),
        _vector("Lcl Scaling", (1, 1, 1), "Lcl Scaling", "", "A"),
        _p("Visibility", "Visibility", "", "A", 1.0),
        _p("Visibility Inheritance", "Visibility Inheritance", "", "", np.int32(1))]
    skeleton = [_vector("Color", (0.8, 0.8, 0.8), "ColorRGB", "Color"), _double("Size", 100.0),
                _p("LimbLength", "double", "Number", "H", 1.0)]
    mesh = [_vector("Color", (0.8, 0.8, 0.8), "ColorRGB", "Color"),
            _vector("BBoxMin", (0, 0, 0)), _vector("BBoxMax", (0, 0, 0)),
            _bool("Primary Visibility", True), _bool("Casts Shadows", True),
            _bool("Receive Shadows", True)]
    stack = [_string("Description", ""), _time("LocalStart", 0), _time("LocalStop", 0),
             _time("ReferenceStart", 0), _time("ReferenceStop", 0)]
    layer = [_p("Weight", "Number", "", "A", 100.0), _bool("Mute", False), _bool("Solo", False),
             _bool("Lock", False), _vector("Color", (0.8, 0.8, 0.8), "ColorRGB", "Color"),
             _enum("BlendMode", 0), _enum("RotationAccumulationMode", 0),
             _enum("ScaleAccumulationMode", 0), _p("BlendModeBypass", "ULongLong", "", "", 0)]
    return {"Model": ("FbxNode", node), "NodeAttribute": ("FbxSkeleton", skeleton),
            "Geometry": ("FbxMesh", mesh), "AnimationStack": ("FbxAnimStack", stack),
            "AnimationLayer": ("FbxAnimLayer", layer),
            "AnimationCurveNode": ("FbxAnimCurveNode", [_p("d", "Compound", "", "")])}


def _definitions(objects: list[Node]) -> Node:
    """``Definitions``: per object type in ``objects`` (in order of first appearance) its
    count and template, after the one ``GlobalSettings``."""
    counts: dict[str, int] = {"GlobalSettings": 1}
    for obj in objects:
        counts[obj.name] = counts.get(obj.name, 0) + 1
    templates = _templates()
    children = [Node("Version", [np.int32(100)]),
                Node("Count", [np.int32(sum(counts.values()))])]
    for kind, count in counts.items():
        entry = Node("ObjectType", [kind], [Node("Count", [np.int32(count)])])
        if kind in templates:
            template, props = templates[kind]
            entry.children.append(Node("PropertyTemplate", [template], [_props(*props)]))
        children.append(entry)
    return Node("Definitions", [], children)


def _takes(take: str, stop: int) -> Node:
    return Node("Takes", [], [Node("Current", [take]), Node("Take", [take], [
        Node("FileName", [f"{take}.tak"]), Node("LocalTime", [0, stop]),
        Node("ReferenceTime", [0, stop])])])


# --------------------------------------------------------------------------- the scene
class _Scene:
    """The objects and connections of one document, built joint by joint."""

    def __init__(self, ids: _Ids):
        self.ids = ids
        self.objects: list[Node] = []
        self.connections: list[Node] = []

    def add(self, name: str, props: list, children: list[Node]) -> int:
        oid = self.ids()
        self.objects.append(Node(name, [oid, *props], children))
        return oid

    def connect(self, child: int, parent: int, prop: str | None = None) -> None:
        self.connections.append(Node("C", ["OO", child, parent] if prop is None else
                                     ["OP", child, parent, prop]))


def _model(props: list[Node]) -> list[Node]:
    return [Node("Version", [np.int32(232)]), _props(*props),
            Node("MultiLayer", [np.int32(0)]), Node("MultiTake", [np.int32(0)]),
            Node("Shading", [True]), Node("Culling", ["CullingOff"])]


def _curve(times: np.ndarray, values: np.ndarray) -> list[Node]:
    """The records of an ``AnimationCurve``: one linear key per time."""
    return [Node("Default", [float(values[0])]), Node("KeyVer", [np.int32(4008)]),
            Node("KeyTime", [times]), Node("KeyValueFloat", [values.astype(np.float32)]),
            Node("KeyAttrFlags", [np.array([_KEY_FLAGS], dtype=np.int32)]),
            Node("KeyAttrDataFloat", [_KEY_DATA.copy()]),
            Node("KeyAttrRefCount", [np.array([len(times)], dtype=np.int32)])]


def _bind_world(bind_q: np.ndarray, bind_pos: np.ndarray) -> np.ndarray:
    """``(J, 4, 4)`` joints' world matrices at bind [cm]."""
    m = np.tile(np.eye(4), (len(bind_q), 1, 1))
    m[:, :3, :3] = to_matrix(bind_q)
    m[:, :3, 3] = bind_pos * CENTIMETRES_PER_METRE
    return m


def _influences(mesh) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Per joint weighing on ``mesh``: ``(joint, vertex indices (int32), weights)``, vertices
    ascending, a joint listed twice for one vertex summed."""
    V, K = mesh.joints.shape
    joint = np.asarray(mesh.joints, dtype=np.int64).reshape(-1)
    weight = np.asarray(mesh.weights, dtype=float).reshape(-1)
    vertex = np.repeat(np.arange(V, dtype=np.int64), K)
    keep = weight > 0
    joint, weight, vertex = joint[keep], weight[keep], vertex[keep]
    key = joint * V + vertex
    order = np.argsort(key, kind="stable")
    key, weight = key[order], weight[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    if len(key):
        key, weight = key[starts], np.add.reduceat(weight, starts)
    joints_of, vertices = key // V, key % V
    out = []
    for j in np.unique(joints_of):
        sel = joints_of == j
        out.append((int(j), vertices[sel].astype(np.int32), weight[sel]))
    return out


def _check(motion: Motion, character: Character | None) -> None:
    sk = motion.skeleton
    if motion.num_frames == 0:
        raise ExportError("the motion has no frames to write")
    if character is not None:
        check_fits(character, motion)
    for j, name in enumerate(sk.names):
        if "\x00" in name or "\x01" in name:
            raise ExportError(f"joint {j} ({name!r}) has a control character in its name, "
                              "which FBX uses to separate a name from its class")


def fbx_document(motion: Motion, character: Character | None = None, *,
                 name: str | None = None) -> Node:
    """The FBX document tree of ``motion`` (on ``character``, whose meshes and skin it then
    holds) with one take called ``name`` (the motion's name by default); see the module notes.

    Raises:
        ExportError: for a motion without frames, or one not on ``character``'s skeleton.
    """
    _check(motion, character)
    sk = motion.skeleton
    J, F = sk.num_joints, motion.num_frames
    take = name if name is not None else (motion.name or "motion")
    bind_q = (np.asarray(character.bind_rotations, dtype=float) if character is not None else
              np.tile([0.0, 0.0, 0.0, 1.0], (J, 1)))
    parent_q = np.tile([0.0, 0.0, 0.0, 1.0], (J, 1))
    parent_q[1:] = bind_q[sk.parents[1:]]
    to_local = qconj(parent_q)
    rest_t = qrot(to_local, sk.offsets) * CENTIMETRES_PER_METRE
    rest_q = qmul(to_local, bind_q)
    local_t = qrot(to_local[None], motion.local_translations()) * CENTIMETRES_PER_METRE
    local_q = qmul(to_local[None], qmul(motion.rotations, bind_q[None]))
    rate, _ = frame_rate(motion.fps)
    times = np.rint(np.arange(F) * (FBX_TICKS_PER_SECOND / rate)).astype(np.int64)
    stop = int(times[-1])

    ids = _Ids()
    scene = _Scene(ids)
    models = []
    for j in range(J):
        seq, fbx_order = rotation_order(sk.rotation_orders[j])
        rest_euler = _euler_xyz(rest_q[j][None], seq, unwrap=False)[0]
        props = [_bool("RotationActive", True), _enum("InheritType", 1),
                 _int("DefaultAttributeIndex", 0),
                 _vector("Lcl Translation", rest_t[j], "Lcl Translation", "", "A+"),
                 _vector("Lcl Rotation", rest_euler, "Lcl Rotation", "", "A+")]
        if fbx_order:
            props.insert(0, _enum("RotationOrder", fbx_order))
        model = scene.add("Model", [_name(sk.names[j], "Model"), "LimbNode"],
                          _model(props))
        attribute = scene.add("NodeAttribute", [_name(sk.names[j], "NodeAttribute"),
                                                "LimbNode"],
                              [_props(_double("Size", 100.0)), Node("TypeFlags", ["Skeleton"])])
        scene.connect(attribute, model)
        scene.connect(model, models[sk.parents[j]] if j else 0)
        models.append(model)

    bind_world = _bind_world(bind_q, _rest_positions(sk))
    pose_nodes = [(m, np.eye(4)) for m in _meshes(scene, character, models, bind_world)]
    pose_nodes += list(zip(models, bind_world))
    scene.add("Pose", [_name(take, "Pose"), "BindPose"], [
        Node("Type", ["BindPose"]), Node("Version", [np.int32(100)]),
        Node("NbPoseNodes", [np.int32(len(pose_nodes))])] + [
        Node("PoseNode", [], [Node("Node", [m]), Node("Matrix", [_matrix(w)])])
        for m, w in pose_nodes])

    stack = scene.add("AnimationStack", [_name(take, "AnimStack"), ""], [_props(
        _time("LocalStart", 0), _time("LocalStop", stop), _time("ReferenceStart", 0),
        _time("ReferenceStop", stop))])
    layer = scene.add("AnimationLayer", [_name("BaseLayer", "AnimLayer"), ""], [])
    scene.connect(layer, stack)
    for j in range(J):
        seq, _ = rotation_order(sk.rotation_orders[j])
        euler = _euler_xyz(local_q[:, j], seq, unwrap=True)
        for channel, prop, values in (("T", "Lcl Translation", local_t[:, j]),
                                      ("R", "Lcl Rotation", euler)):
            node = scene.add("AnimationCurveNode", [_name(channel, "AnimCurveNode"), ""], [
                _props(*(_p(f"d|{axis}", "Number", "", "A", float(values[0, a]))
                         for a, axis in enumerate("XYZ")))])
            scene.connect(node, layer)
            scene.connect(node, models[j], prop)
            for a, axis in enumerate("XYZ"):
                curve = scene.add("AnimationCurve", [_name("", "AnimCurve"), ""],
                                  _curve(times, values[:, a]))
                scene.connect(curve, node, f"d|{axis}")

    root = Node("FBX", [np.int32(FBX_VERSION)], _header())
    root.children += [_global_settings(motion.fps, stop)] + _documents(ids, take)
    root.children += [_definitions(scene.objects), Node("Objects", [], scene.objects),
                      Node("Connections", [], scene.connections), _takes(take, stop)]
    return root


def _meshes(scene: _Scene, character: Character | None, models: list[int],
            bind_world: np.ndarray) -> list[int]:
    """Add ``character``'s skinned meshes (model, geometry, skin, clusters); their models."""
    if character is None:
        return []
    out = []
    for mesh in character.meshes:
        model = scene.add("Model", [_name(mesh.name, "Model"), "Mesh"], _model([
            _int("DefaultAttributeIndex", 0), _enum("InheritType", 1)]))
        scene.connect(model, 0)
        tris = np.asarray(mesh.triangles, dtype=np.int32).reshape(-1, 3).copy()
        tris[:, 2] = -tris[:, 2] - 1                    # a polygon's last index is ~index
        records = [_props(), Node("GeometryVersion", [np.int32(124)]),
                   Node("Vertices", [np.asarray(mesh.positions, dtype=np.float64).reshape(-1) *
                                     CENTIMETRES_PER_METRE]),
                   Node("PolygonVertexIndex", [tris.reshape(-1)])]
        if mesh.normals is not None:
            records.append(Node("LayerElementNormal", [np.int32(0)], [
                Node("Version", [np.int32(101)]), Node("Name", [""]),
                Node("MappingInformationType", ["ByVertice"]),
                Node("ReferenceInformationType", ["Direct"]),
                Node("Normals", [np.asarray(mesh.normals, dtype=np.float64).reshape(-1)])]))
            records.append(Node("Layer", [np.int32(0)], [
                Node("Version", [np.int32(100)]), Node("LayerElement", [], [
                    Node("Type", ["LayerElementNormal"]), Node("TypedIndex", [np.int32(0)])])]))
        geometry = scene.add("Geometry", [_name(mesh.name, "Geometry"), "Mesh"], records)
        scene.connect(geometry, model)
        skin = scene.add("Deformer", [_name(mesh.name, "Deformer"), "Skin"], [
            Node("Version", [np.int32(101)]), Node("Link_DeformAcuracy", [50.0])])
        scene.connect(skin, geometry)
        for j, vertices, weights in _influences(mesh):
            link = bind_world[j]
            cluster = scene.add("Deformer", [_name(character.skeleton.names[j], "SubDeformer"),
                                             "Cluster"], [
                Node("Version", [np.int32(100)]), Node("UserData", ["", ""]),
                Node("Indexes", [vertices]), Node("Weights", [weights.astype(np.float64)]),
                Node("Transform", [_matrix(np.linalg.inv(link))]),
                Node("TransformLink", [_matrix(link)]),
                Node("TransformAssociateModel", [_matrix(np.eye(4))])])
            scene.connect(cluster, skin)
            scene.connect(models[j], cluster)
        out.append(model)
    return out


def format_fbx(motion: Motion, character: Character | None = None, *,
               name: str | None = None) -> bytes:
    """The bytes :func:`write_fbx` writes."""
    return encode_binary(fbx_document(motion, character, name=name), FBX_VERSION)


def write_fbx(motion: Motion, path: str | os.PathLike, *, character: Character | None = None,
              name: str | None = None) -> None:
    """Write ``motion`` as binary FBX 7.4 at ``path``, atomically (see the module notes):
    the skeleton, the motion as one take called ``name`` (the motion's name by default), and,
    with ``character``, its skinned meshes. The previous file at ``path`` stays intact when
    anything fails.

    Raises:
        ExportError: for a motion without frames, or one not on ``character``'s skeleton.
        FileWriteError: when the file cannot be written.
    """
    atomic_write(path, format_fbx(motion, character, name=name))
