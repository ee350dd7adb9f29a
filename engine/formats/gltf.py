"""glTF 2.0 characters: read a skinned skeleton, its meshes and animations; write them back.

:func:`read_gltf` takes ``.glb`` (binary container) and ``.gltf`` (JSON with external
``.bin`` files or ``data:`` URIs) and returns a :class:`Character`: an engine
:class:`~engine.skeleton.Skeleton`, the skinned meshes as plain numpy arrays, and every
animation as an engine :class:`~engine.motion.Motion` resampled at a fixed frame rate.
:func:`write_gltf` writes a motion on a character as a ``.glb`` (or ``.gltf``) with the mesh,
the skin and one animation. Both are written from the specification with numpy alone.

How a glTF skin becomes a Skeleton
----------------------------------
glTF states a skin's *bind pose* only through its inverse bind matrices (IBM): joint ``j``'s
bind matrix is ``inverse(IBM_j)``, in the space the mesh's vertices are authored in. Where
that space sits in the scene is not stated: the skinning equation
``v' = sum_j w_j * world_j * IBM_j * v`` only needs it relative to the joints' animated world
transforms. The reader places it so that the skeleton's top joint lies in its bind pose exactly
where the scene puts that joint (its node's world transform): ``F = world_top * IBM_top``, and
every bind matrix becomes ``F * inverse(IBM_j)`` and every bind vertex ``F * v``. This folds
everything above the skeleton into it - a rotated or scaled root node, a Z-up bind pose authored
at 0.01 scale under a node that turns it Y-up at 100x (Robot Expressive) - and it is exact for
the animations, whose world transforms include the same ancestors.

The Skeleton's zero-rotation pose *is* that bind pose: each joint's rest frame is the world's
axes, its offset the world vector from its parent's bind position (so forward kinematics of
:meth:`Character.rest_motion` gives the bind positions to rounding). The joint's own glTF axes
in the bind pose (the bone orientation a DCC tool shows) are kept as
:attr:`Character.bind_rotations`; a glTF local rotation ``g_j`` becomes the engine's
``r_j = B_parent * g_j * inverse(B_j)`` and :func:`write_gltf` turns it back. The node's own
rest TRS (the scene's default pose, not the bind pose) is kept as ``node_translations`` etc.

Uniform scale anywhere above or inside the skeleton is baked into offsets, translations and
vertex positions (the engine has no scale). A bind pose with non-uniform scale or shear is
refused (:class:`~engine.errors.GLTFError`); an animation that scales a joint non-uniformly is
left out with a note.

Channels (for BVH export): every joint rotates in ``Zrotation Xrotation Yrotation``; the root
and every joint whose local translation moves (in any animation or in the node default pose,
beyond 1e-5 of the character's size) also carry ``Xposition Yposition Zposition`` ("absolute":
they replace the offset). Units are metres and +Y up, the format's own convention.

What the reader refuses, with the file and the JSON path (``accessors[12].count``): a
truncated GLB, a bad magic or version, chunk lengths that run past the end, malformed JSON,
missing or short buffers, indices out of range, accessors that overrun their buffer view,
sparse indices out of range, non-increasing animation times, output counts that do not match
their inputs, and a file that requires an extension it does not decode (``extensionsRequired``:
meshopt compression, GPU instancing, ...; required material, texture and light extensions are
ignored, Draco-compressed primitives are left out with a note, quantized attributes are
read). Sparse accessors, strided buffer views, normalized integers, ``matrix`` nodes,
several skins sharing joints, unnamed joints (``joint_<node>``) and several root joints (joined
under their common ancestor, or a new ``root``) are supported.
"""
from __future__ import annotations

import base64
import binascii
import json
import math
import os
import re
import struct
import urllib.parse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import limits
from ..errors import ExportError, GLTFError
from ..fileio import atomic_write, reading
from ..motion import Motion
from ..quaternions import qconj, qmul, qrot, to_matrix
from ..skeleton import EndSite, Skeleton
from ..units import SourceFrame, up_axis_rotation
from .figure import with_lying_doubt

__all__ = ["Mesh", "Character", "read_gltf", "write_gltf", "format_gltf", "DEFAULT_FPS",
           "GLTF_SOURCE", "ROTATION_LAYOUT", "POSITION_LAYOUT"]

#: the frame rate animations are resampled at unless told otherwise
DEFAULT_FPS = 30.0
#: rotation channels of every glTF joint (for BVH export)
ROTATION_LAYOUT = ("Zrotation", "Xrotation", "Yrotation")
#: position channels of the root and of every joint whose translation moves
POSITION_LAYOUT = ("Xposition", "Yposition", "Zposition")
#: glTF's own convention: metres, +Y up
GLTF_SOURCE = SourceFrame(units="m", scale=1.0, up_axis="+Y", detected=False,
                          reason="glTF: metres and +Y up by the format's definition")

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_COMPONENTS = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
               5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_COMPONENT_NAMES = {5120: "BYTE", 5121: "UNSIGNED_BYTE", 5122: "SHORT",
                    5123: "UNSIGNED_SHORT", 5125: "UNSIGNED_INT", 5126: "FLOAT"}
_UNSIGNED = (5121, 5123, 5125)
_TYPES = {"SCALAR": (1, 1), "VEC2": (2, 1), "VEC3": (3, 1), "VEC4": (4, 1),
          "MAT2": (2, 2), "MAT3": (3, 3), "MAT4": (4, 4)}
#: how far a bind matrix may stray from a uniformly scaled rotation (float32 exports of
#: Blender rigs carry ~1e-5) before it is refused
_SCALE_TOL = 1e-3
#: a joint gets position channels when its local translation strays this far (a fraction of
#: the character's size) from its bind offset
_MOVE_TOL = 1e-5
_EXTRAS_KEY = "motionComposer"
#: longest animation resampled (about 5.5 hours at 30 fps)
_MAX_FRAMES = 600_000


# =========================================================================== data
@dataclass(frozen=True, eq=False)
class Mesh:
    """One skinned triangle mesh in the bind pose, as plain arrays (internal metres, +Y up).

    Attributes:
        name: the glTF mesh's name (or its node's), with ``#k`` for its k-th primitive.
        positions: ``(V, 3)`` [m] bind-pose vertex positions in the world.
        normals: ``(V, 3)`` unit bind-pose normals, or ``None``.
        triangles: ``(T, 3)`` vertex indices.
        joints: ``(V, K)`` skeleton joint index per influence (already mapped from the skin's
            own joint numbering through :attr:`Character.skin_joints`).
        weights: ``(V, K)`` influence weights; each row sums to 1.
        skin: the glTF skin index, or ``None`` for a rigid part (a mesh node hanging under a
            joint node, bound to that joint with weight 1).
        node: the glTF node that instantiates it.
    """

    name: str
    positions: np.ndarray
    normals: np.ndarray | None
    triangles: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    skin: int | None
    node: int

    @property
    def num_vertices(self) -> int:
        return len(self.positions)

    @property
    def num_triangles(self) -> int:
        return len(self.triangles)


@dataclass(frozen=True, eq=False)
class Character:
    """A skinned character from a glTF file.

    Attributes:
        name: the file's stem.
        skeleton: the joints (union of the skins read), zero rotations = the bind pose.
        meshes: skinned meshes (and rigid parts bound to one joint).
        motions: the animations, resampled at ``fps`` (performer clips, or targets).
        bind_rotations: ``(J, 4)`` each joint's glTF axes in the bind pose, in the world.
        bind_scales: ``(J,)`` each joint's uniform world scale in the bind pose (file data).
        node_translations, node_rotations, node_scales: ``(J, 3)``, ``(J, 4)``, ``(J, 3)`` the
            joint nodes' own rest TRS as written in the file (local, file units; identity for
            a joint the reader added).
        node_indices: ``(J,)`` the glTF node of each joint (``-1`` for an added root).
        skin_joints: per skin read, the skeleton joint index of each of its joints.
        skin_frames: per skin read, the 4x4 matrix taking its bind space (the space of its
            inverse bind matrices and vertices) to the world (see the module notes); NaN for
            a skin without inverse bind matrices (its default node pose is its bind pose).
        skin_names: per skin read, its name (or ``skin_<index>``).
        skins: the glTF indices of the skins read.
        node_pose: the scene's default pose (node TRS without animation) as a 1-frame motion.
        fps: the rate the animations were resampled at.
        path: the file read.
        notes: what the reader changed or left out, in sentences.
    """

    name: str
    skeleton: Skeleton
    meshes: tuple[Mesh, ...]
    motions: tuple[Motion, ...]
    bind_rotations: np.ndarray
    bind_scales: np.ndarray
    node_translations: np.ndarray
    node_rotations: np.ndarray
    node_scales: np.ndarray
    node_indices: np.ndarray
    skin_joints: tuple[np.ndarray, ...]
    skin_frames: np.ndarray
    skin_names: tuple[str, ...]
    skins: tuple[int, ...]
    node_pose: Motion
    fps: float = DEFAULT_FPS
    path: str | None = None
    notes: tuple[str, ...] = ()

    @property
    def bind_positions(self) -> np.ndarray:
        """``(J, 3)`` [m] world joint positions in the bind pose."""
        return _rest_positions(self.skeleton)

    def rest_motion(self, frame_time: float | None = None) -> Motion:
        """A one-frame motion in the bind pose (zero rotations), e.g. a retargeting target."""
        sk = self.skeleton
        rot = np.zeros((1, sk.num_joints, 4))
        rot[..., 3] = 1.0
        tra = sk.offsets[sk.translated][None].copy()
        return Motion(sk, rot, tra, frame_time or 1.0 / self.fps, name=self.name)

    def motion(self, name: str) -> Motion:
        """The animation called ``name``."""
        for m in self.motions:
            if m.name == name:
                return m
        known = ", ".join(m.name for m in self.motions) or "none"
        raise GLTFError(f"no animation named {name!r} (animations: {known})", self.path)

    @property
    def num_vertices(self) -> int:
        return sum(m.num_vertices for m in self.meshes)

    @property
    def num_triangles(self) -> int:
        return sum(m.num_triangles for m in self.meshes)


def _rest_positions(sk: Skeleton) -> np.ndarray:
    pos = np.empty((sk.num_joints, 3))
    pos[0] = sk.offsets[0]
    for j in range(1, sk.num_joints):
        pos[j] = pos[sk.parents[j]] + sk.offsets[j]
    return pos


# =========================================================================== small maths
def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``(..., 4)`` x-y-z-w (any norm) -> ``(..., 3, 3)`` rotation matrices."""
    q = np.asarray(q, dtype=float)
    return to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


def _trs_matrix(t: np.ndarray, q: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` from translations ``(..., 3)``, rotations ``(..., 4)``, scales."""
    shape = np.broadcast_shapes(t.shape[:-1], q.shape[:-1], s.shape[:-1])
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = _quat_to_matrix(q) * np.asarray(s)[..., None, :]
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def _polar(m: np.ndarray):
    """Nearest rotations ``(..., 3, 3)`` of ``m``, its singular values and determinants."""
    u, sig, vt = np.linalg.svd(m)
    det = np.linalg.det(m)
    flip = np.linalg.det(u @ vt) < 0
    if np.any(flip):
        u = u.copy()
        u[flip, :, 2] *= -1
    return u @ vt, sig, det


def _matrix_to_quat(m: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    shape = m.shape[:-2]
    if not int(np.prod(shape)):
        return np.zeros(shape + (4,))
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat().reshape(shape + (4,))


def _decompose(m: np.ndarray):
    """TRS of one 4x4 matrix (rotation by polar decomposition, scale signed by det)."""
    t = m[:3, 3].copy()
    rot, sig, det = _polar(m[:3, :3])
    s = np.linalg.norm(m[:3, :3], axis=0)
    if det < 0:
        s[0] = -s[0]
    return t, _matrix_to_quat(rot), s


def _slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation, ``(N, 4)`` pairs at ``(N,)`` fractions."""
    d = np.sum(q0 * q1, axis=-1)
    q1 = np.where((d < 0)[:, None], -q1, q1)
    d = np.abs(d)
    near = d > 0.9995
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin = np.sin(theta)
    safe = np.where(near, 1.0, sin)
    a = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    b = np.where(near, u, np.sin(u * theta) / safe)
    out = a[:, None] * q0 + b[:, None] * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"



def check_fits(character: Character, motion: Motion) -> None:
    """Raise :class:`~engine.errors.ExportError` unless ``motion`` is on ``character``'s
    skeleton (the same joints and parents), as a writer of the two together needs."""
    sk, csk = motion.skeleton, character.skeleton
    if csk.names != sk.names or not np.array_equal(csk.parents, sk.parents):
        raise ExportError(f"the motion's skeleton ({sk.num_joints} joints) is not the "
                          f"character {character.name!r}'s ({csk.num_joints} joints); "
                          "retarget the motion onto the character first")

# =========================================================================== container
def _read_bytes(path) -> bytes:
    with reading(path, GLTFError, "a glTF file"):
        return Path(path).read_bytes()


def _parse_json(raw: bytes, path, where: str) -> dict:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise GLTFError(f"the JSON is not UTF-8 text (byte {exc.start})", path, where) from None
    try:
        js = json.loads(text)
    except json.JSONDecodeError as exc:
        raise GLTFError(f"malformed JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})",
                        path, where) from None
    except RecursionError:
        raise GLTFError("malformed JSON: nested too deeply", path, where) from None
    if not isinstance(js, dict):
        raise GLTFError(f"the JSON must be an object, not {type(js).__name__}", path, where)
    asset = js.get("asset")
    if not isinstance(asset, dict) or not isinstance(asset.get("version"), str):
        raise GLTFError("missing or malformed; every glTF file has an asset object with its "
                        "version (\"2.0\")", path, "asset.version" if isinstance(asset, dict)
                        else "asset")
    if asset["version"].split(".")[0] != "2":
        raise GLTFError(f"glTF version {asset['version']!r}; this reader takes glTF 2.x", path,
                        "asset.version")
    _check_required_extensions(js, path)
    return js


#: required extensions the reader handles: Draco-compressed primitives are left out with a
#: note (the skeleton, skin and animations are read), quantized attributes are integer
#: accessors (read like any other)
_HANDLED_EXTENSIONS = frozenset({"KHR_draco_mesh_compression", "KHR_mesh_quantization"})
#: extensions that change only how a file looks (materials, textures, lights): the reader
#: reads no appearance, so a file that requires one is read without it
_APPEARANCE_PREFIXES = ("KHR_materials_", "KHR_texture_", "EXT_texture_", "KHR_lights_",
                        "EXT_lights_")
#: what the reader cannot decode, in words, for the message
_UNDECODED = {"EXT_meshopt_compression": "meshopt-compressed buffer views",
              "KHR_meshopt_compression": "meshopt-compressed buffer views"}


def _check_required_extensions(js: dict, path) -> None:
    """Refuse a file that requires an extension the reader does not decode: the spec asks a
    loader to, and read without it the file gives wrong data (a meshopt-compressed buffer
    view points at a placeholder buffer that holds no bytes, an instancing extension moves
    meshes), not an error that names the cause."""
    required = js.get("extensionsRequired", [])
    if not isinstance(required, list) or not all(isinstance(e, str) for e in required):
        raise GLTFError(f"expected a list of extension names, found {required!r}", path,
                        "extensionsRequired")
    missing = [e for e in required if e not in _HANDLED_EXTENSIONS
               and not e.startswith(_APPEARANCE_PREFIXES)]
    if missing:
        what = "; ".join(f"{e} ({_UNDECODED[e]})" if e in _UNDECODED else e for e in missing)
        raise GLTFError(f"the file requires {what}, which this reader does not decode; "
                        f"expected a glTF file without it (write it again without that "
                        f"compression or extension)", path, "extensionsRequired")


def _parse_container(data: bytes, path) -> tuple[dict, bytes | None]:
    if not data:
        raise GLTFError("the file is empty; expected glTF 2.0 (a .glb binary or .gltf JSON)",
                        path)
    if data[:4] == _GLB_MAGIC:
        return _parse_glb(data, path)
    looks_json = data.removeprefix(b"\xef\xbb\xbf").lstrip()[:1] == b"{"
    if not looks_json:
        raise GLTFError(f"bad magic {data[:4]!r}: a binary glTF (.glb) starts with b'glTF' and "
                        "a .gltf file is JSON starting with '{'", path, "GLB header")
    return _parse_json(data, path, "JSON"), None


def _parse_glb(data: bytes, path) -> tuple[dict, bytes | None]:
    if len(data) < 12:
        raise GLTFError(f"the file has {len(data)} bytes; a GLB header needs 12 (truncated?)",
                        path, "GLB header")
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise GLTFError(f"GLB version {version}; this reader takes version 2 (glTF 2.0)", path,
                        "GLB header")
    if length != len(data):
        why = "truncated?" if length > len(data) else "extra bytes after the end"
        raise GLTFError(f"the header gives a length of {length} bytes but the file has "
                        f"{len(data)} ({why})", path, "GLB header")
    chunks = []
    offset = 12
    while offset < length:
        k = len(chunks)
        if offset + 8 > length:
            raise GLTFError(f"chunk {k} starts at byte {offset} but its 8-byte header runs past "
                            f"the end of the file ({length} bytes)", path, f"GLB chunk {k}")
        clen, ctype = struct.unpack_from("<II", data, offset)
        start, end = offset + 8, offset + 8 + clen
        if end > length:
            raise GLTFError(f"the chunk length {clen} runs past the end of the file (only "
                            f"{length - start} bytes follow its header at byte {offset})", path,
                            f"GLB chunk {k}")
        chunks.append((ctype, data[start:end]))
        offset = end
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise GLTFError("the first chunk must be the JSON chunk (type 0x4E4F534A)", path,
                        "GLB chunk 0")
    js = _parse_json(chunks[0][1], path, "GLB JSON chunk")
    binary = next((c for t, c in chunks[1:] if t == _CHUNK_BIN), None)
    return js, binary


def _is_index(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


#: a URI scheme (RFC 3986: a letter, then letters, digits, ``+``, ``-`` or ``.``, then ``:``)
_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
#: a Windows drive (``C:\\``, ``C:/``, ``C:``)
_WINDOWS_DRIVE = re.compile(r"^[A-Za-z]:(?:[/\\]|$)")


class _Doc:
    """The JSON with checked access, the buffers and decoded accessors (cached)."""

    def __init__(self, path, js: dict, binary: bytes | None):
        self.path = os.fspath(path) if path is not None else None
        self.folder = os.path.dirname(os.path.abspath(self.path)) if self.path else os.getcwd()
        self.js = js
        self.binary = binary
        self._buffers: dict[int, np.ndarray] = {}
        self._accessors: dict[int, np.ndarray] = {}

    def error(self, where: str | None, problem: str) -> GLTFError:
        return GLTFError(problem, self.path, where)

    # ------------------------------------------------------------------ JSON access
    def array(self, name: str) -> list:
        value = self.js.get(name, [])
        if not isinstance(value, list):
            raise self.error(name, f"expected an array, found {type(value).__name__}")
        return value

    def item(self, name: str, index, where: str) -> dict:
        items = self.array(name)
        if not _is_index(index):
            raise self.error(where, f"expected an index into {name}, found {index!r}")
        if index >= len(items):
            raise self.error(where, f"refers to {name}[{index}], but the file has "
                                    f"{len(items)} {name}")
        obj = items[index]
        if not isinstance(obj, dict):
            raise self.error(f"{name}[{index}]", f"expected an object, found "
                                                 f"{type(obj).__name__}")
        return obj

    def integer(self, obj: dict, key: str, where: str, *, default=None, minimum: int = 0) -> int:
        if key not in obj:
            if default is None:
                raise self.error(f"{where}.{key}", "missing (required)")
            return default
        v = obj[key]
        if not (isinstance(v, int) and not isinstance(v, bool)) or v < minimum:
            raise self.error(f"{where}.{key}", f"expected a whole number >= {minimum}, found "
                                               f"{v!r}")
        return v

    def numbers(self, obj: dict, key: str, where: str, n: int, default) -> np.ndarray:
        if key not in obj:
            return np.array(default, dtype=float)
        v = obj[key]
        ok = isinstance(v, list) and len(v) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        if ok:
            arr = np.array(v, dtype=float)
            ok = limits.all_usable(arr)
        if not ok:
            raise self.error(f"{where}.{key}", f"expected {n} finite numbers of magnitude at "
                                               f"most {limits.MAX_MAGNITUDE:g}, found "
                                               f"{str(v)[:80]}")
        return arr

    # ------------------------------------------------------------------ external files
    def check_references(self) -> None:
        """Refuse, before anything is read, every buffer or image URI that is not a ``data:``
        URI or a relative file inside the file's own folder (see :meth:`local_file`)."""
        for name in ("buffers", "images"):
            for i, obj in enumerate(self.array(name)):
                if isinstance(obj, dict) and "uri" in obj:
                    uri = obj["uri"]
                    where = f"{name}[{i}].uri"
                    if not isinstance(uri, str):
                        raise self.error(where, f"expected a string, found {uri!r}")
                    if not uri.startswith("data:"):
                        self.local_file(uri, where)

    def local_file(self, uri: str, where: str) -> str:
        """The path of a relative file URI, refused (a :class:`GLTFError` naming ``where``)
        when it is absolute (``/etc/hostname``, ``C:\\x``), names a URL or any scheme
        (``file:``, ``http:``; nothing is ever fetched), or leaves the file's own folder
        (``../x.bin``, ``%2e%2e/x.bin``, or a symlink pointing out of it)."""
        if _URI_SCHEME.match(uri) and not _WINDOWS_DRIVE.match(uri):
            scheme = uri.partition(":")[0]
            raise self.error(where, f"{uri[:80]!r} names a {scheme}: URL; only data: URIs and "
                                    "files beside the glTF file are read (nothing is fetched)")
        rel = urllib.parse.unquote(uri)
        if "\0" in rel:
            raise self.error(where, f"{uri[:80]!r} contains a NUL character")
        unified = rel.replace("\\", "/")
        if unified.startswith("/") or _WINDOWS_DRIVE.match(unified):
            raise self.error(where, f"{uri[:80]!r} is an absolute path; a glTF file may refer "
                                    "only to files in its own folder, by a relative path")
        folder = os.path.realpath(self.folder)
        file = os.path.realpath(os.path.join(folder, unified))
        if os.path.commonpath([folder, file]) != folder:
            raise self.error(where, f"{uri[:80]!r} leads out of the glTF file's folder "
                                    f"({folder}); a glTF file may refer only to files inside it")
        return file

    # ------------------------------------------------------------------ binary data
    def buffer(self, index, where: str) -> np.ndarray:
        b = self.item("buffers", index, where)
        if index in self._buffers:
            return self._buffers[index]
        bw = f"buffers[{index}]"
        length = self.integer(b, "byteLength", bw, minimum=1)
        uri = b.get("uri")
        if uri is None:
            if index != 0 or self.binary is None:
                raise self.error(bw, "has no uri, and the file has no GLB binary chunk to "
                                     "stand for it (missing buffer)")
            data = self.binary
        elif not isinstance(uri, str):
            raise self.error(f"{bw}.uri", f"expected a string, found {uri!r}")
        elif uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma:
                raise self.error(f"{bw}.uri", "a data: URI without ',' before its data")
            if head.endswith(";base64"):
                try:
                    data = base64.b64decode(payload, validate=True)
                except (binascii.Error, ValueError) as exc:
                    raise self.error(f"{bw}.uri", f"the base64 data is malformed ({exc})") \
                        from None
            else:
                data = urllib.parse.unquote_to_bytes(payload)
        else:
            file = self.local_file(uri, f"{bw}.uri")
            try:
                data = Path(file).read_bytes()
            except FileNotFoundError:
                raise self.error(f"{bw}.uri", f"the buffer file {uri!r} is missing (looked for "
                                              f"{file})") from None
            except OSError as exc:
                raise self.error(f"{bw}.uri", f"the buffer file {uri!r} cannot be read: "
                                              f"{exc.strerror or exc}") from None
        if len(data) < length:
            raise self.error(f"{bw}.byteLength", f"{length} bytes declared, but the data has "
                                                 f"only {len(data)} (truncated?)")
        arr = np.frombuffer(data, dtype=np.uint8, count=length)
        self._buffers[index] = arr
        return arr

    def buffer_view(self, index, where: str) -> tuple[np.ndarray, int | None]:
        bv = self.item("bufferViews", index, where)
        w = f"bufferViews[{index}]"
        buf_index = self.integer(bv, "buffer", w)
        buf = self.buffer(buf_index, f"{w}.buffer")
        offset = self.integer(bv, "byteOffset", w, default=0)
        length = self.integer(bv, "byteLength", w, minimum=1)
        if offset + length > len(buf):
            raise self.error(w, f"bytes {offset} to {offset + length} lie outside "
                                f"buffers[{buf_index}], which has {len(buf)} bytes")
        stride = None
        if "byteStride" in bv:
            stride = self.integer(bv, "byteStride", w, minimum=1)
        return buf[offset:offset + length], stride

    def accessor(self, index, where: str, *, types=None, components=None) -> np.ndarray:
        """Accessor ``index`` decoded: ``(count,)`` scalars, ``(count, n)`` vectors or
        ``(count, r, c)`` matrices; float64 for FLOAT and normalized data, else integers."""
        a = self.item("accessors", index, where)
        aw = f"accessors[{index}]"
        ctype = a.get("componentType")
        if not _is_index(ctype) or ctype not in _COMPONENTS:
            raise self.error(f"{aw}.componentType", f"expected one of "
                                                    f"{sorted(_COMPONENTS)}, found {ctype!r}")
        typ = a.get("type")
        if not isinstance(typ, str) or typ not in _TYPES:
            raise self.error(f"{aw}.type", f"expected one of {', '.join(_TYPES)}, found "
                                           f"{typ!r}")
        if types and typ not in types:
            raise self.error(where, f"expected an accessor of type {' or '.join(types)}, but "
                                    f"{aw} is {typ}")
        if components and ctype not in components:
            names = " or ".join(_COMPONENT_NAMES[c] for c in components)
            raise self.error(where, f"expected {names} components, but {aw} has "
                                    f"{_COMPONENT_NAMES[ctype]}")
        if index in self._accessors:
            return self._accessors[index]
        count = self.integer(a, "count", aw, minimum=1)
        normalized = a.get("normalized", False)
        if not isinstance(normalized, bool):
            raise self.error(f"{aw}.normalized", f"expected true or false, found "
                                                 f"{normalized!r}")
        if normalized and ctype in (5125, 5126):
            raise self.error(f"{aw}.normalized", f"{_COMPONENT_NAMES[ctype]} components "
                                                 "cannot be normalized")
        dtype = _COMPONENTS[ctype]
        rows, cols = _TYPES[typ]
        n = rows * cols
        elem, picks = _element_layout(rows, cols, dtype.itemsize)
        if "bufferView" in a:
            view, stride = self.buffer_view(a["bufferView"], f"{aw}.bufferView")
            stride = stride or elem
            if stride < elem:
                raise self.error(f"bufferViews[{a['bufferView']}].byteStride",
                                 f"{stride} bytes is less than one element of {aw} "
                                 f"({elem} bytes)")
            offset = self.integer(a, "byteOffset", aw, default=0)
            need = offset + stride * (count - 1) + elem
            if need > len(view):
                raise self.error(f"{aw}.count", f"{count} elements of {elem} bytes (stride "
                                 f"{stride}) from byte {offset} need {need} bytes, but "
                                 f"bufferViews[{a['bufferView']}] has {len(view)} (accessor "
                                 "out of range)")
            raw = np.lib.stride_tricks.as_strided(view[offset:], shape=(count, elem),
                                                  strides=(stride, 1), writeable=False)
            data = np.ascontiguousarray(raw[:, picks]).view(dtype).reshape(count, n)
        else:
            data = np.zeros((count, n), dtype=dtype)
        if "sparse" in a:
            data = self._sparse(a["sparse"], f"{aw}.sparse", data, dtype, elem, picks, count, n)
        if normalized:
            info = np.iinfo(dtype)
            out = data.astype(float) / info.max
            if info.min < 0:
                out = np.maximum(out, -1.0)
        elif ctype == 5126:
            with np.errstate(invalid="ignore"):
                out = data.astype(float)
            if not limits.all_usable(out):
                bad = int(np.flatnonzero(~(np.abs(out) <= limits.MAX_MAGNITUDE).all(axis=1))[0])
                raise self.error(aw, f"element {bad} is not a finite number of magnitude at "
                                     f"most {limits.MAX_MAGNITUDE:g}")
        else:
            out = data.astype(np.int64)
        if cols > 1:
            out = out.reshape(count, cols, rows).transpose(0, 2, 1)   # column-major storage
        elif rows == 1:
            out = out.reshape(count)
        out.setflags(write=False)
        self._accessors[index] = out
        return out

    def _sparse(self, sp, sw, data, dtype, elem, picks, count, n):
        if not isinstance(sp, dict):
            raise self.error(sw, "expected an object")
        scount = self.integer(sp, "count", sw, minimum=1)
        if scount > count:
            raise self.error(f"{sw}.count", f"{scount} sparse elements in an accessor of "
                                            f"{count}")
        ind, val = sp.get("indices"), sp.get("values")
        if not isinstance(ind, dict) or not isinstance(val, dict):
            raise self.error(sw, "needs 'indices' and 'values' objects")
        ictype = ind.get("componentType")
        if not _is_index(ictype) or ictype not in _UNSIGNED:
            raise self.error(f"{sw}.indices.componentType", f"expected UNSIGNED_BYTE, "
                             f"UNSIGNED_SHORT or UNSIGNED_INT, found {ictype!r}")
        idtype = _COMPONENTS[ictype]
        parts = []
        for obj, w, size in ((ind, f"{sw}.indices", idtype.itemsize), (val, f"{sw}.values",
                                                                         elem)):
            view, _ = self.buffer_view(obj.get("bufferView"), f"{w}.bufferView")
            off = self.integer(obj, "byteOffset", w, default=0)
            need = off + size * scount
            if need > len(view):
                raise self.error(w, f"{scount} elements of {size} bytes from byte {off} need "
                                    f"{need} bytes, but bufferViews[{obj['bufferView']}] has "
                                    f"{len(view)} (accessor out of range)")
            parts.append(view[off:need])
        idx = parts[0].view(idtype).astype(np.int64)
        if np.any(idx >= count):
            bad = int(idx[idx >= count][0])
            raise self.error(f"{sw}.indices", f"index {bad} is outside the accessor's {count} "
                                              "elements")
        if np.any(np.diff(idx) <= 0):
            raise self.error(f"{sw}.indices", "sparse indices must increase strictly")
        values = np.ascontiguousarray(parts[1].reshape(scount, elem)[:, picks]).view(dtype)
        data = data.copy()
        data[idx] = values.reshape(scount, n)
        return data


def _element_layout(rows: int, cols: int, size: int):
    """Bytes per element and the byte positions holding values (matrix columns of 1- and
    2-byte components are padded to 4 bytes)."""
    if cols == 1:
        return rows * size, np.arange(rows * size)
    col = rows * size
    stride = (col + 3) // 4 * 4
    picks = np.concatenate([np.arange(c * stride, c * stride + col) for c in range(cols)])
    return cols * stride, picks


# =========================================================================== scene graph
@dataclass
class _Graph:
    parent: np.ndarray          # (N,) parent node or -1
    order: list                 # DFS order, parents first, children in file order
    depth: np.ndarray
    t: np.ndarray               # (N, 3) rest TRS (decomposed for matrix nodes)
    q: np.ndarray
    s: np.ndarray
    local: np.ndarray           # (N, 4, 4) rest local matrices
    world: np.ndarray           # (N, 4, 4) rest world matrices
    has_matrix: np.ndarray


def _graph(doc: _Doc) -> _Graph:
    nodes = doc.array("nodes")
    N = len(nodes)
    parent = np.full(N, -1, dtype=np.intp)
    kids: list[list[int]] = []
    for i, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise doc.error(f"nodes[{i}]", "expected an object")
        children = node.get("children", [])
        if not isinstance(children, list):
            raise doc.error(f"nodes[{i}].children", "expected an array of node indices")
        for k, c in enumerate(children):
            if not _is_index(c) or c >= N:
                raise doc.error(f"nodes[{i}].children[{k}]", f"expected a node index below "
                                                             f"{N}, found {c!r}")
            if c == i:
                raise doc.error(f"nodes[{i}].children[{k}]", "a node cannot be its own child")
            if parent[c] != -1:
                raise doc.error(f"nodes[{i}].children[{k}]", f"node {c} already is a child of "
                                f"node {parent[c]}; a node has at most one parent")
            parent[c] = i
        kids.append(list(children))
    order: list[int] = []
    depth = np.zeros(N, dtype=np.intp)
    stack = [i for i in range(N) if parent[i] < 0][::-1]
    while stack:
        i = stack.pop()
        order.append(i)
        if parent[i] >= 0:
            depth[i] = depth[parent[i]] + 1
        stack.extend(kids[i][::-1])
    if len(order) < N:
        lost = sorted(set(range(N)) - set(order))
        raise doc.error("nodes", f"nodes {lost[:6]} are each other's children (a cycle)")
    t = np.zeros((N, 3))
    q = np.zeros((N, 4))
    q[:, 3] = 1.0
    s = np.ones((N, 3))
    local = np.tile(np.eye(4), (N, 1, 1))
    has_matrix = np.zeros(N, dtype=bool)
    for i, node in enumerate(nodes):
        w = f"nodes[{i}]"
        if "matrix" in node:
            m = doc.numbers(node, "matrix", w, 16, None).reshape(4, 4).T
            if not np.allclose(m[3], (0, 0, 0, 1), atol=1e-6):
                raise doc.error(f"{w}.matrix", "the last row must be 0 0 0 1 (an affine "
                                               "transform)")
            local[i] = m
            t[i], q[i], s[i] = _decompose(m)
            has_matrix[i] = True
            continue
        t[i] = doc.numbers(node, "translation", w, 3, (0.0, 0.0, 0.0))
        r = doc.numbers(node, "rotation", w, 4, (0.0, 0.0, 0.0, 1.0))
        norm = np.linalg.norm(r)
        if norm < 1e-6:
            raise doc.error(f"{w}.rotation", "a zero quaternion is not a rotation")
        q[i] = r / norm
        s[i] = doc.numbers(node, "scale", w, 3, (1.0, 1.0, 1.0))
        local[i] = _trs_matrix(t[i], q[i], s[i])
    world = local.copy()
    for i in order:
        if parent[i] >= 0:
            world[i] = world[parent[i]] @ local[i]
    return _Graph(parent, order, depth, t, q, s, local, world, has_matrix)


# =========================================================================== animations
def _sample_channel(doc: _Doc, a: int, sampler_index: int, samplers: list, times: np.ndarray,
                    path: str, width: int) -> np.ndarray:
    """Values ``(len(times), width)`` of one sampler at ``times``."""
    sw = f"animations[{a}].samplers[{sampler_index}]"
    sampler = samplers[sampler_index]
    if not isinstance(sampler, dict):
        raise doc.error(sw, "expected an object")
    t = doc.accessor(sampler.get("input"), f"{sw}.input", types=("SCALAR",),
                     components=(5126,))
    out = doc.accessor(sampler.get("output"), f"{sw}.output")
    mode = sampler.get("interpolation", "LINEAR")
    if mode not in ("LINEAR", "STEP", "CUBICSPLINE"):
        raise doc.error(f"{sw}.interpolation", f"expected LINEAR, STEP or CUBICSPLINE, found "
                                                f"{mode!r}")
    out = np.asarray(out, dtype=float).reshape(len(out), -1)
    if out.shape[1] != width:
        raise doc.error(f"{sw}.output", f"a {path} channel needs {width} values per key, "
                                        f"found {out.shape[1]}")
    K = len(t)
    if np.any(np.diff(t) < 0):
        bad = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise doc.error(f"{sw}.input", f"key times must increase; key {bad + 1} "
                                       f"({t[bad + 1]:g} s) comes before key {bad} "
                                       f"({t[bad]:g} s)")
    expected = 3 * K if mode == "CUBICSPLINE" else K
    if len(out) != expected:
        raise doc.error(f"{sw}.output", f"{len(out)} values for {K} key times; "
                                        f"{mode} needs {expected}")
    if mode == "CUBICSPLINE":
        tri = out.reshape(K, 3, width)
        a_in, v, b_out = tri[:, 0], tri[:, 1], tri[:, 2]
    else:
        v = out
    if path == "rotation":
        v = _unit_keys(doc, v, f"{sw}.output")
    idx = np.clip(np.searchsorted(t, times, side="right") - 1, 0, K - 1)
    nxt = np.minimum(idx + 1, K - 1)
    dt = t[nxt] - t[idx]
    u = np.where(dt > 0, (times - t[idx]) / np.where(dt > 0, dt, 1.0), 0.0)
    u = np.clip(u, 0.0, 1.0)
    if mode == "STEP":
        res = v[idx].copy()
    elif mode == "LINEAR":
        if path == "rotation":
            res = _slerp(v[idx], v[nxt], u)
        else:
            res = v[idx] + (v[nxt] - v[idx]) * u[:, None]
    else:
        u2, u3 = u * u, u * u * u
        h00 = 2 * u3 - 3 * u2 + 1
        h10 = u3 - 2 * u2 + u
        h01 = -2 * u3 + 3 * u2
        h11 = u3 - u2
        res = (h00[:, None] * v[idx] + (h10 * dt)[:, None] * b_out[idx] +
               h01[:, None] * v[nxt] + (h11 * dt)[:, None] * a_in[nxt])
    if path == "rotation":
        norm = np.linalg.norm(res, axis=1, keepdims=True)
        res = res / np.where(norm > 1e-12, norm, 1.0)
    return res


def _unit_keys(doc: _Doc, keys: np.ndarray, where: str) -> np.ndarray:
    """Rotation keys ``(K, 4)`` scaled to unit length (interpolation assumes them); a zero
    quaternion (an accessor without a buffer view is all zeros) is refused."""
    norm = np.linalg.norm(keys, axis=1)
    if np.any(norm < 1e-12):
        k = int(np.flatnonzero(norm < 1e-12)[0])
        raise doc.error(where, f"key {k} is a zero quaternion, which is not a rotation")
    return keys / norm[:, None]


def _animation_times(doc: _Doc, a: int, anim: dict, fps: float) -> tuple[np.ndarray, float]:
    samplers = anim.get("samplers", [])
    if not isinstance(samplers, list):
        raise doc.error(f"animations[{a}].samplers", "expected an array")
    end = 0.0
    for k, sampler in enumerate(samplers):
        if isinstance(sampler, dict) and "input" in sampler:
            t = doc.accessor(sampler["input"], f"animations[{a}].samplers[{k}].input",
                             types=("SCALAR",), components=(5126,))
            end = max(end, float(t.max()))
    frames = end * fps
    if frames > _MAX_FRAMES:
        raise doc.error(f"animations[{a}]", f"its keys run to {end:.6g} s, more than "
                                            f"{_MAX_FRAMES} frames at {fps:g} fps")
    n = int(round(frames)) if abs(frames - round(frames)) < 1e-4 else int(math.ceil(frames))
    times = np.minimum(np.arange(n + 1) / fps, end)
    return times, end


# =========================================================================== reading
@dataclass
class _Pose:
    """World joint frames of one clip (or the default pose), engine axes."""

    name: str
    world_rot: np.ndarray       # (F, J, 4) engine world rotations (bind = identity)
    positions: np.ndarray       # (F, J, 3)


def read_gltf(path: str | os.PathLike, *, skin: int | str | None = None,
              fps: float | None = None, up_axis: str | None = None) -> Character:
    """Read a glTF 2.0 character (``.glb`` or ``.gltf``).

    Args:
        skin: read only this skin (index or name); by default every skin, their joints
            joined into one skeleton.
        fps: the rate animations are resampled at; by default the rate a file written by
            :func:`write_gltf` records, else :data:`DEFAULT_FPS`.
        up_axis: the axis the file's figure stands along (one of :data:`engine.units.AXES`),
            for a file written with another axis up against the format's +Y (Blender's
            exporter with "+Y Up" unticked writes +Z): the whole scene is turned onto +Y
            (skeleton, meshes, animations). By default the format's +Y.

    Raises:
        GLTFError: for a malformed file or one this reader cannot use (no skin, a bind
            pose with non-uniform scale), naming the file and the JSON path.
    """
    path = os.fspath(path)
    js, binary = _parse_container(_read_bytes(path), path)
    doc = _Doc(path, js, binary)
    doc.check_references()
    source = GLTF_SOURCE
    if up_axis is not None and up_axis != GLTF_SOURCE.up_axis:
        try:
            turn = up_axis_rotation(up_axis)
        except ValueError as exc:
            raise GLTFError(str(exc), path) from None
        _graph(doc)                 # the node tree as written is checked first
        _stand_up(doc, turn)
        source = dataclasses.replace(GLTF_SOURCE, up_axis=up_axis, reason=(
            f"glTF: metres; read with {up_axis} up as given (the format's own is +Y)"))
    return _build(doc, skin=skin, fps=fps, source=source)


def _stand_up(doc: _Doc, turn: np.ndarray) -> None:
    """Turn the whole scene by ``turn`` (3x3): one node of its own, parent of every node
    that has none, so that animated roots and every world transform below them turn too
    (the reader takes every node's world transform from the node tree, not from
    ``scenes``)."""
    nodes = doc.array("nodes")
    children = {c for node in nodes for c in node.get("children", [])}
    roots = [i for i in range(len(nodes)) if i not in children]
    nodes.append({"name": "up axis", "rotation": _matrix_to_quat(turn).tolist(),
                  "children": roots})


def _build(doc: _Doc, *, skin, fps, source: SourceFrame = GLTF_SOURCE) -> Character:
    """The :class:`Character` of a parsed file: its joints, bind pose, poses and meshes."""
    notes: list[str] = []
    nodes = doc.array("nodes")
    g = _graph(doc)
    skins = doc.array("skins")
    if not skins:
        raise doc.error("skins", "the file has no skin; a character needs a skinned skeleton "
                                 "(skins[].joints)")
    selected = _select_skins(doc, skins, skin)
    hint = _writer_hint(doc)
    fps = _frame_rate(doc, fps, hint)

    skin_nodes, ibms = _skin_joints(doc, nodes, skins, selected, notes)
    joints = _joint_tree(g, nodes, skin_nodes, notes)
    bind, frames = _bind_matrices(doc, g, nodes, joints, selected, skin_nodes, ibms, notes)
    rot, bind_scale = _bind_rotations(doc, bind, joints, selected, skin_nodes)
    bind_pos = bind[:, :3, 3].copy()
    offsets = bind_pos.copy()
    offsets[1:] -= bind_pos[joints.parents[1:]]
    end_sites = _end_sites(g, nodes, joints, bind, bind_pos)
    size = _extent(bind_pos, end_sites)
    height = float(np.ptp(bind_pos[:, 1]))
    if height > 20.0:
        notes.append(f"the bind pose is {height:.3g} m tall in glTF metres; the file was "
                     "probably authored in centimetres (scale it where sizes matter)")

    default, poses = _poses(doc, g, joints, rot, fps, notes)
    channels = _channels(joints, offsets, size, [default] + poses, hint)
    skeleton = Skeleton(names=joints.names, parents=joints.parents, offsets=offsets,
                        channels=channels, end_sites=end_sites, source=source)
    motions = tuple(_pose_motion(p, skeleton, joints.parents, 1.0 / fps) for p in poses)
    doubted = with_lying_doubt(skeleton, "bind pose", motions)
    if doubted is not skeleton:
        skeleton = doubted
        motions = tuple(m.replace(skeleton=skeleton) for m in motions)
    stem = Path(doc.path).stem if doc.path else "character"
    node_pose = _pose_motion(default, skeleton, joints.parents, 1.0 / fps)
    node_pose = node_pose.replace(name=f"{stem} (default pose)")

    skin_maps = [np.array([joints.index[n] for n in js], dtype=np.intp) for js in skin_nodes]
    meshes = _meshes(doc, g, selected, skin_maps, frames, ibms, joints, bind, notes)

    joint_t, joint_q, joint_s = _node_rest(g, joints.nodes)
    skin_names = tuple(str(skins[s].get("name") or f"skin_{s}") for s in selected)
    return Character(
        name=stem, skeleton=skeleton, meshes=tuple(meshes), motions=motions,
        bind_rotations=_frozen(_matrix_to_quat(rot)), bind_scales=_frozen(bind_scale),
        node_translations=_frozen(joint_t), node_rotations=_frozen(joint_q),
        node_scales=_frozen(joint_s), node_indices=_frozen(np.array(joints.nodes, np.intp)),
        skin_joints=tuple(_frozen(m) for m in skin_maps),
        skin_frames=_frozen(np.array(frames)), skin_names=skin_names,
        skins=tuple(selected), node_pose=node_pose, fps=float(fps), path=doc.path,
        notes=tuple(notes))


def _writer_hint(doc: _Doc) -> dict:
    """What :func:`write_gltf` recorded in ``asset.extras`` (frame rate, position channels),
    or ``{}``."""
    extras = doc.js.get("asset", {}).get("extras", {})
    hint = extras.get(_EXTRAS_KEY, {}) if isinstance(extras, dict) else {}
    return hint if isinstance(hint, dict) else {}


def _frame_rate(doc: _Doc, fps: float | None, hint: dict) -> float:
    """[frames/s] the rate asked for, else the one the writer recorded, else the default."""
    if fps is None:
        hinted = hint.get("fps")
        fps = float(hinted) if isinstance(hinted, (int, float)) and hinted > 0 else DEFAULT_FPS
    if not (math.isfinite(fps) and 1.0 / limits.MAX_FRAME_TIME <= fps <= limits.MAX_MAGNITUDE):
        raise GLTFError(f"the frame rate must be a positive number of frames per second, at "
                        f"least {1.0 / limits.MAX_FRAME_TIME:g}, not {fps!r}", doc.path)
    return fps


# ---------------------------------------------------------------- the joints
@dataclass
class _Joints:
    """The skeleton's ``J`` joints among the scene's nodes.

    Attributes:
        nodes: ``(J,)`` the node of each joint, parents first (scene order); ``-1`` for a new
            root joining root joints that lie in separate node trees.
        index: node -> joint index.
        parents: ``(J,)`` parent joint index, ``-1`` for the root.
        names: ``(J,)`` unique joint names.
        members: the joint nodes: every selected skin's joints, and the common ancestor that
            joins several root joints.
    """

    nodes: list[int]
    index: dict[int, int]
    parents: np.ndarray
    names: list[str]
    members: set[int]


def _joint_ancestor(g: _Graph, members: set[int], n: int) -> int:
    """The nearest node above node ``n`` that is in ``members``, or -1."""
    p = g.parent[n]
    while p >= 0 and p not in members:
        p = g.parent[p]
    return int(p)


def _skin_joints(doc: _Doc, nodes: list, skins: list, selected: list[int],
                 notes: list[str]) -> tuple[list[list[int]], list[np.ndarray | None]]:
    """Per selected skin, its joint nodes and its inverse bind matrices ``(len(joints), 4, 4)``
    (``None`` when the skin has none: its default node pose is its bind pose)."""
    skin_nodes: list[list[int]] = []
    ibms: list[np.ndarray | None] = []
    for s in selected:
        sw = f"skins[{s}]"
        joints = skins[s].get("joints")
        if not isinstance(joints, list) or not joints:
            raise doc.error(f"{sw}.joints", "expected a non-empty array of node indices")
        seen: set[int] = set()
        for k, n in enumerate(joints):
            if not _is_index(n) or n >= len(nodes):
                raise doc.error(f"{sw}.joints[{k}]", f"expected a node index below "
                                                     f"{len(nodes)}, found {n!r}")
            if n in seen:
                raise doc.error(f"{sw}.joints[{k}]", f"node {n} is listed twice")
            seen.add(n)
        if "skeleton" in skins[s]:
            doc.item("nodes", skins[s]["skeleton"], f"{sw}.skeleton")
        if "inverseBindMatrices" in skins[s]:
            ibm = doc.accessor(skins[s]["inverseBindMatrices"], f"{sw}.inverseBindMatrices",
                               types=("MAT4",), components=(5126,))
            if len(ibm) < len(joints):
                raise doc.error(f"{sw}.inverseBindMatrices", f"{len(ibm)} matrices for "
                                                             f"{len(joints)} joints")
            ibms.append(np.asarray(ibm[:len(joints)], dtype=float))
        else:
            ibms.append(None)
            notes.append(f"skin {s} has no inverse bind matrices: the default node pose is "
                         "taken as its bind pose")
        skin_nodes.append(list(joints))
    return skin_nodes, ibms


def _joint_tree(g: _Graph, nodes: list, skin_nodes: list[list[int]],
                notes: list[str]) -> _Joints:
    """The skins' joints as one tree: each joint's parent is its nearest joint ancestor, and
    several root joints are joined under their common ancestor node (or a new ``root``)."""
    members = set().union(*map(set, skin_nodes))
    roots = [n for n in g.order if n in members and _joint_ancestor(g, members, n) < 0]
    synthetic = False
    if len(roots) > 1:
        common = _common_ancestor(g, roots)
        if common >= 0:
            members.add(common)
            notes.append(f"{len(roots)} root joints: their common ancestor node "
                         f"{common} ({nodes[common].get('name', 'unnamed')}) joins them "
                         "as the skeleton's root")
        else:
            synthetic = True
            notes.append(f"{len(roots)} root joints in separate node trees: a new joint "
                         "'root' at the origin joins them")
    order = [n for n in g.order if n in members]
    joint_nodes = ([-1] if synthetic else []) + order
    index = {n: j for j, n in enumerate(joint_nodes)}
    parents = np.full(len(joint_nodes), -1, dtype=np.intp)
    for j, n in enumerate(joint_nodes):
        if n >= 0:
            a = _joint_ancestor(g, members, n)
            parents[j] = index[a] if a >= 0 else (0 if synthetic else -1)
    if synthetic:
        parents[0] = -1
    names = _joint_names(nodes, joint_nodes, notes)
    return _Joints(joint_nodes, index, parents, names, members)


def _common_ancestor(g: _Graph, roots: list[int]) -> int:
    """The lowest node above every node of ``roots``, or -1 when they are in separate trees."""
    chains = []
    for r in roots:
        chain, p = [], g.parent[r]
        while p >= 0:
            chain.append(int(p))
            p = g.parent[p]
        chains.append(chain)
    common = [p for p in chains[0] if all(p in c for c in chains[1:])]
    return common[0] if common else -1


# ---------------------------------------------------------------- the bind pose
def _node_world(g: _Graph, n: int) -> np.ndarray:
    """``(4, 4)`` node ``n``'s rest world matrix; the identity for a new root (``n = -1``)."""
    return np.eye(4) if n < 0 else g.world[n]


def _skin_bind(doc: _Doc, g: _Graph, nodes: list, s: int, joints: list[int],
               ibm: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """One skin's world bind matrices ``(len(joints), 4, 4)`` and its frame ``F = world_top *
    IBM_top`` ``(4, 4)`` (see the module notes; NaN without inverse bind matrices)."""
    sw = f"skins[{s}].inverseBindMatrices"
    if ibm is None:
        return np.array([g.world[n] for n in joints]), np.full((4, 4), np.nan)
    for k in range(len(joints)):
        if not np.allclose(ibm[k, 3], (0, 0, 0, 1), atol=1e-5):
            raise doc.error(sw, f"matrix {k} (joint {nodes[joints[k]].get('name', k)})"
                                " is not affine (its last row must be 0 0 0 1)")
    det = np.linalg.det(ibm[:, :3, :3])
    if np.any(np.abs(det) < 1e-30):
        k = int(np.argmin(np.abs(det)))
        raise doc.error(sw, f"matrix {k} (joint {nodes[joints[k]].get('name', k)}) is "
                            "singular")
    ref = min(range(len(joints)), key=lambda k: (g.depth[joints[k]],
                                                g.order.index(joints[k])))
    frame = g.world[joints[ref]] @ ibm[ref]
    return frame @ np.linalg.inv(ibm), frame


def _bind_matrices(doc: _Doc, g: _Graph, nodes: list, joints: _Joints, selected: list[int],
                   skin_nodes: list[list[int]], ibms: list[np.ndarray | None],
                   notes: list[str]) -> tuple[np.ndarray, list[np.ndarray]]:
    """``(J, 4, 4)`` world bind matrices [m] of the joints (from the first skin that lists a
    joint; a joint no skin lists is bound where its node rests) and each skin's frame."""
    J = len(joints.nodes)
    bind = np.empty((J, 4, 4))
    have = np.zeros(J, dtype=bool)
    frames = []
    for s, js, ibm in zip(selected, skin_nodes, ibms):
        mats, frame = _skin_bind(doc, g, nodes, s, js, ibm)
        frames.append(frame)
        for k, n in enumerate(js):
            j = joints.index[n]
            if not have[j]:
                bind[j] = mats[k]
                have[j] = True
            else:
                d = float(np.linalg.norm(bind[j, :3, 3] - mats[k, :3, 3]))
                size = float(np.ptp(bind[have, :3, 3], axis=0).max()) if have.sum() > 1 else 1
                if d > 1e-4 * max(size, 1e-9):
                    notes.append(f"skin {s} binds joint {joints.names[j]!r} {d:.3g} m away "
                                 "from the first skin that lists it; its meshes use their own "
                                 "skin")
    for j, n in enumerate(joints.nodes):
        if not have[j]:
            bind[j] = _node_world(g, n)
    if not np.all(np.isfinite(bind)):
        j = int(np.flatnonzero(~np.all(np.isfinite(bind), axis=(1, 2)))[0])
        raise doc.error("skins", f"joint {joints.names[j]!r} has no finite bind matrix (its "
                                 "inverse bind matrix is nearly singular)")
    return bind, frames


def _bind_rotations(doc: _Doc, bind: np.ndarray, joints: _Joints, selected: list[int],
                    skin_nodes: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """The bind matrices' rotations ``(J, 3, 3)`` and uniform scales ``(J,)``; a mirroring,
    non-uniform or sheared bind matrix is refused."""
    rot, sig, det = _polar(bind[:, :3, :3])
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        spread = sig.max(axis=1) / np.maximum(sig.min(axis=1), 1e-300) - 1.0
    for j in range(len(joints.nodes)):
        if det[j] <= 0 or spread[j] > _SCALE_TOL:
            which = next((f"skins[{s}].inverseBindMatrices" for s, js in
                          zip(selected, skin_nodes) if joints.nodes[j] in js), "nodes")
            what = "a mirroring (negative) scale" if det[j] <= 0 else \
                f"a non-uniform scale or shear (scales {', '.join(f'{x:.4g}' for x in sig[j])})"
            raise doc.error(which, f"joint {joints.names[j]!r} has {what} in its bind pose; "
                                   "only uniform scale can be baked into the skeleton")
    return rot, sig.mean(axis=1)


def _end_sites(g: _Graph, nodes: list, joints: _Joints, bind: np.ndarray,
               bind_pos: np.ndarray) -> list[EndSite]:
    """End Sites: the childless, meshless non-joint children of joints (Blender's ``_end``
    bones), their offsets [m] in the bind pose."""
    end_sites = []
    for j, n in enumerate(joints.nodes):
        if n < 0:
            continue
        for c in nodes[n].get("children", []):
            node = nodes[c]
            if c in joints.members or node.get("children") or "mesh" in node or \
                    "camera" in node:
                continue
            tip = (bind[j] @ g.local[c])[:3, 3]
            end_sites.append(EndSite(j, tip - bind_pos[j], node.get("name") or
                                     f"{joints.names[j]}_end"))
    return end_sites


def _extent(bind_pos: np.ndarray, end_sites: list[EndSite]) -> float:
    """[m] the character's size: the largest extent of its joints and End Sites along an axis
    in the bind pose (``bind_pos`` ``(J, 3)``)."""
    return float(np.ptp(np.concatenate([bind_pos] + [[bind_pos[e.parent] + e.offset]
                                                      for e in end_sites]), axis=0).max())


# ---------------------------------------------------------------- poses
def _poses(doc: _Doc, g: _Graph, joints: _Joints, rot: np.ndarray, fps: float,
           notes: list[str]) -> tuple[_Pose, list[_Pose]]:
    """The scene's default node pose and every animation the skeleton can take, sampled at
    ``fps`` (``rot``: ``(J, 3, 3)`` the bind rotations)."""
    needed = set()
    for n in joints.nodes:
        while n >= 0 and n not in needed:
            needed.add(n)
            n = g.parent[n]
    needed_order = [n for n in g.order if n in needed]
    default = _pose_from_world(np.array([_node_world(g, n) for n in joints.nodes])[None], rot,
                               joints.parents, "default pose")
    poses: list[_Pose] = []
    weights_note = False
    for a, anim in enumerate(doc.array("animations")):
        if not isinstance(anim, dict):
            raise doc.error(f"animations[{a}]", "expected an object")
        name = anim.get("name") or f"animation_{a}"
        times, _ = _animation_times(doc, a, anim, fps)
        world, used, skipped = _animate(doc, a, anim, g, needed_order, times)
        weights_note |= skipped
        G = np.array([world[n] if n >= 0 else np.broadcast_to(np.eye(4), world[
            needed_order[0]].shape) for n in joints.nodes]).transpose(1, 0, 2, 3)
        pose = _pose_from_world(G, rot, joints.parents, name)
        if pose is None:
            notes.append(f"animation {name!r} scales a joint non-uniformly (or beyond "
                         "finite numbers); it was left out")
            continue
        if not used:
            notes.append(f"animation {name!r} moves no joint of the skeleton")
        poses.append(pose)
    if weights_note:
        notes.append("morph-target weight channels are not used")
    if default is None:
        raise doc.error("nodes", "the default pose scales a joint non-uniformly")
    return default, poses


# ---------------------------------------------------------------- translated joints
def _channels(joints: _Joints, offsets: np.ndarray, size: float, poses: list[_Pose],
              hint: dict) -> tuple[tuple[str, ...], ...]:
    """Per joint, its BVH channels: rotations, and positions for the root and every joint whose
    local translation strays from its offset ``(J, 3)`` [m] in one of ``poses`` (or that the
    writer listed)."""
    J = len(joints.nodes)
    tol = _MOVE_TOL * max(size, 1e-9)
    moving = np.zeros(J, dtype=bool)
    moving[0] = True
    for pose in poses:
        local_t = _local_translations(pose, joints.parents)
        dev = np.linalg.norm(local_t - offsets, axis=-1).max(axis=0)
        moving |= dev > tol
    listed = hint.get("positionChannels")
    if isinstance(listed, list):
        for nm in listed:
            if nm in joints.names:
                moving[joints.names.index(nm)] = True
    return tuple(POSITION_LAYOUT + ROTATION_LAYOUT if moving[j] else ROTATION_LAYOUT
                 for j in range(J))


def _node_rest(g: _Graph, joint_nodes: list[int]):
    """The joints' node rest TRS: translations ``(J, 3)`` [m], rotations ``(J, 4)`` (x, y, z, w)
    and scales ``(J, 3)``; a new root (node -1) has the identity."""
    joint_t = np.array([g.t[n] if n >= 0 else np.zeros(3) for n in joint_nodes])
    joint_q = np.array([g.q[n] if n >= 0 else np.array([0, 0, 0, 1.0]) for n in joint_nodes])
    joint_s = np.array([g.s[n] if n >= 0 else np.ones(3) for n in joint_nodes])
    return joint_t, joint_q, joint_s


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


def _select_skins(doc: _Doc, skins: list, skin) -> list[int]:
    for s, item in enumerate(skins):
        if not isinstance(item, dict):
            raise doc.error(f"skins[{s}]", "expected an object")
    if skin is None:
        return list(range(len(skins)))
    names = [str(item.get("name") or f"skin_{s}") for s, item in enumerate(skins)]
    if isinstance(skin, str):
        if skin in names:
            return [names.index(skin)]
    elif _is_index(skin) and skin < len(skins):
        return [int(skin)]
    raise GLTFError(f"no skin {skin!r}; the file has skins "
                    f"{', '.join(f'{s} ({n})' for s, n in enumerate(names))}", doc.path)


def _joint_names(nodes: list, joint_nodes: list[int], notes: list[str]) -> list[str]:
    names = []
    unnamed = 0
    for n in joint_nodes:
        if n < 0:
            names.append("root")
            continue
        name = nodes[n].get("name")
        if not isinstance(name, str) or not name.strip():
            name = f"joint_{n}"
            unnamed += 1
        names.append(name)
    if unnamed:
        notes.append(f"{_plural(unnamed, 'joint')} without a name named by node index "
                     "(joint_<node>)")
    counts: dict[str, int] = {}
    for nm in names:
        counts[nm] = counts.get(nm, 0) + 1
    renamed = []
    taken = set(names)
    for j, n in enumerate(joint_nodes):
        if counts[names[j]] > 1:
            new = f"{names[j]}_{n}"
            while new in taken:
                new += "_"
            taken.add(new)
            renamed.append(f"{names[j]} -> {new}")
            names[j] = new
    if renamed:
        notes.append("repeated joint names made unique: " + ", ".join(renamed))
    return names


def _animate(doc: _Doc, a: int, anim: dict, g: _Graph, needed_order: list[int],
             times: np.ndarray):
    """World matrices ``{node: (F, 4, 4)}`` of the needed nodes over ``times``."""
    aw = f"animations[{a}]"
    F = len(times)
    samplers = anim.get("samplers", [])
    channels = anim.get("channels", [])
    if not isinstance(samplers, list) or not isinstance(channels, list):
        raise doc.error(aw, "expected 'samplers' and 'channels' arrays")
    needed = set(needed_order)
    trs: dict[int, list] = {}
    used = False
    weights = False
    for c, ch in enumerate(channels):
        cw = f"{aw}.channels[{c}]"
        if not isinstance(ch, dict) or not isinstance(ch.get("target"), dict):
            raise doc.error(cw, "expected an object with a target")
        target = ch["target"]
        sampler = ch.get("sampler")
        if not _is_index(sampler) or sampler >= len(samplers):
            raise doc.error(f"{cw}.sampler", f"expected a sampler index below "
                                             f"{len(samplers)}, found {sampler!r}")
        path = target.get("path")
        if path not in ("translation", "rotation", "scale", "weights"):
            if path is None:
                raise doc.error(f"{cw}.target.path", "missing (required)")
            continue                          # an extension's path: not ours
        if "node" not in target:
            continue                          # animated through an extension
        node = target["node"]
        doc.item("nodes", node, f"{cw}.target.node")
        if path == "weights":
            weights = True
            continue
        if node not in needed:
            continue
        width = 4 if path == "rotation" else 3
        values = _sample_channel(doc, a, sampler, samplers, times, path, width)
        slot = trs.setdefault(node, [None, None, None])
        slot[("translation", "rotation", "scale").index(path)] = values
        used = True
    world: dict[int, np.ndarray] = {}
    for n in needed_order:
        if n in trs:
            t, q, s = trs[n]
            t = g.t[n][None] if t is None else t
            q = g.q[n][None] if q is None else q
            s = g.s[n][None] if s is None else s
            local = np.broadcast_to(_trs_matrix(t, q, s), (F, 4, 4))
        else:
            local = np.broadcast_to(g.local[n], (F, 4, 4))
        p = g.parent[n]
        world[n] = local.copy() if p < 0 else world[p] @ local
    return world, used, weights


def _pose_from_world(G: np.ndarray, bind_rot: np.ndarray, parents: np.ndarray, name: str):
    """Engine world rotations and positions from glTF world matrices ``(F, J, 4, 4)``; None
    when a joint is scaled non-uniformly."""
    if not np.all(np.isfinite(G)):
        return None
    rot, sig, det = _polar(G[..., :3, :3])
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        spread = sig.max(axis=-1) / np.maximum(sig.min(axis=-1), 1e-300) - 1.0
    if not np.all(spread <= _SCALE_TOL) or np.any(det <= 0):
        return None
    engine = rot @ np.swapaxes(bind_rot, -1, -2)
    return _Pose(name, _matrix_to_quat(engine), G[..., :3, 3].copy())


def _local_translations(pose: _Pose, parents: np.ndarray) -> np.ndarray:
    """``(F, J, 3)`` each joint's position in its parent's (engine) frame; the root's world."""
    out = pose.positions.copy()
    p = parents[1:]
    out[:, 1:] = qrot(qconj(pose.world_rot[:, p]), pose.positions[:, 1:] - pose.positions[:, p])
    return out


def _pose_motion(pose: _Pose, skeleton: Skeleton, parents: np.ndarray,
                 frame_time: float) -> Motion:
    local = pose.world_rot.copy()
    local[:, 1:] = qmul(qconj(pose.world_rot[:, parents[1:]]), pose.world_rot[:, 1:])
    local /= np.linalg.norm(local, axis=-1, keepdims=True)
    tra = _local_translations(pose, parents)[:, skeleton.translated]
    return Motion(skeleton, local, tra, frame_time, name=pose.name)


# =========================================================================== meshes
def _meshes(doc: _Doc, g: _Graph, selected, skin_maps, frames, ibms, tree: _Joints, bind,
            notes) -> list[Mesh]:
    nodes = doc.array("nodes")
    out: list[Mesh] = []
    loose = 0
    morphs = False
    other_skin = 0
    skipped_prims: dict[str, int] = {}
    normalised = []
    for n in g.order:
        node = nodes[n]
        if "mesh" not in node:
            continue
        m = node["mesh"]
        mesh = doc.item("meshes", m, f"nodes[{n}].mesh")
        prims = mesh.get("primitives")
        mw = f"meshes[{m}]"
        if not isinstance(prims, list) or not prims:
            raise doc.error(f"{mw}.primitives", "expected a non-empty array")
        if "skin" in node:
            s = node["skin"]
            doc.item("skins", s, f"nodes[{n}].skin")
            if s not in selected:
                other_skin += 1
                continue
            k = selected.index(s)
            rigid_joint = None
        else:
            a = n if n in tree.index else _joint_ancestor(g, tree.members, n)
            if a < 0:
                loose += 1
                continue
            rigid_joint = tree.index[a]
            chain = np.eye(4)
            p = n
            while p != a:
                chain = g.local[p] @ chain
                p = g.parent[p]
        base = mesh.get("name") or node.get("name") or f"mesh_{m}"
        for pi, prim in enumerate(prims):
            pw = f"{mw}.primitives[{pi}]"
            if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                raise doc.error(pw, "expected an object with attributes")
            attrs = prim["attributes"]
            mode = prim.get("mode", 4)
            if "extensions" in prim and "KHR_draco_mesh_compression" in prim["extensions"]:
                skipped_prims["Draco-compressed"] = skipped_prims.get("Draco-compressed", 0) + 1
                continue
            if mode not in (4, 5, 6):
                skipped_prims["point or line"] = skipped_prims.get("point or line", 0) + 1
                continue
            if "POSITION" not in attrs:
                skipped_prims["position-less"] = skipped_prims.get("position-less", 0) + 1
                continue
            if prim.get("targets"):
                morphs = True
            pos = np.asarray(doc.accessor(attrs["POSITION"], f"{pw}.attributes.POSITION",
                                          types=("VEC3",)), dtype=float)
            V = len(pos)
            normals = None
            if "NORMAL" in attrs:
                normals = np.asarray(doc.accessor(attrs["NORMAL"], f"{pw}.attributes.NORMAL",
                                                  types=("VEC3",)), dtype=float)
                if len(normals) != V:
                    raise doc.error(f"{pw}.attributes.NORMAL", f"{len(normals)} normals for "
                                                               f"{V} positions")
            tris = _triangles(doc, prim, pw, V, mode)
            name = base if len(prims) == 1 else f"{base}#{pi}"
            if rigid_joint is None:
                if "JOINTS_0" not in attrs or "WEIGHTS_0" not in attrs:
                    skipped_prims["unweighted skinned"] = \
                        skipped_prims.get("unweighted skinned", 0) + 1
                    continue
                joints, weights = _influences(doc, attrs, pw, V, len(skin_maps[k]))
                sums = weights.sum(axis=1)
                off = np.abs(sums - 1.0) > 1e-3
                if np.any(off):
                    normalised.append(f"{name} ({int(off.sum())} of {V} vertices, sums "
                                      f"{sums.min():.3g} to {sums.max():.3g})")
                empty = sums <= 0
                weights = np.where(empty[:, None], 0.0, weights / np.where(empty, 1.0,
                                                                          sums)[:, None])
                if np.any(empty):
                    weights[empty, 0] = 1.0
                raw = joints
                joints = skin_maps[k][raw]
                if ibms[k] is None:
                    # the default pose is the bind pose: the vertices as skinned there
                    skin_m = np.array([g.world[nd] for nd in
                                       doc.js["skins"][selected[k]]["joints"]])
                    blend = np.einsum("vk,vkab->vab", weights, skin_m[raw])
                    positions = np.einsum("vab,vb->va", blend[:, :3, :3], pos) + blend[:, :3, 3]
                    nrm = None if normals is None else np.einsum("vab,vb->va",
                                                                 blend[:, :3, :3], normals)
                else:
                    world_m = frames[k]
                    positions = pos @ world_m[:3, :3].T + world_m[:3, 3]
                    nrm = None if normals is None else normals @ np.linalg.inv(
                        world_m[:3, :3])
                skin_id = selected[k]
            else:
                world_m = bind[rigid_joint] @ chain
                positions = pos @ world_m[:3, :3].T + world_m[:3, 3]
                nrm = None if normals is None else normals @ np.linalg.inv(world_m[:3, :3])
                joints = np.full((V, 1), rigid_joint, dtype=np.intp)
                weights = np.ones((V, 1))
                skin_id = None
            if nrm is not None:
                length = np.linalg.norm(nrm, axis=1, keepdims=True)
                nrm = nrm / np.where(length > 1e-12, length, 1.0)
            out.append(Mesh(name=name, positions=_frozen(positions),
                            normals=None if nrm is None else _frozen(nrm),
                            triangles=_frozen(tris), joints=_frozen(joints.astype(np.intp)),
                            weights=_frozen(weights), skin=skin_id, node=int(n)))
    if normalised:
        notes.append("skin weights that did not sum to 1 were normalised: " +
                     "; ".join(normalised))
    if loose:
        notes.append(f"{_plural(loose, 'mesh node')} not attached to the skeleton left out")
    if other_skin:
        notes.append(f"{_plural(other_skin, 'mesh node')} bound to other skins left out")
    for what, count in skipped_prims.items():
        notes.append(f"{_plural(count, what + ' primitive')} left out")
    if morphs:
        notes.append("morph targets are not used (meshes are in their base shape)")
    rigid = sum(1 for m in out if m.skin is None)
    if rigid:
        notes.append(f"{_plural(rigid, 'rigid mesh part')} under joint nodes bound to their "
                     "joint with weight 1")
    return out


def _triangles(doc: _Doc, prim: dict, pw: str, V: int, mode: int) -> np.ndarray:
    if "indices" in prim:
        idx = doc.accessor(prim["indices"], f"{pw}.indices", types=("SCALAR",),
                           components=_UNSIGNED)
        if len(idx) and int(idx.max()) >= V:
            raise doc.error(f"{pw}.indices", f"vertex index {int(idx.max())} but the primitive "
                                             f"has {V} vertices")
    else:
        idx = np.arange(V)
    idx = np.asarray(idx, dtype=np.int64)
    if mode == 4:
        if len(idx) % 3:
            raise doc.error(f"{pw}.indices" if "indices" in prim else pw,
                            f"{len(idx)} indices is not a whole number of triangles")
        return idx.reshape(-1, 3)
    if len(idx) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    k = np.arange(len(idx) - 2)
    if mode == 5:                             # strip: every other triangle flipped
        a, b = idx[k], idx[k + 1]
        odd = (k % 2) == 1
        return np.stack([np.where(odd, b, a), np.where(odd, a, b), idx[k + 2]], axis=1)
    return np.stack([np.full(len(k), idx[0]), idx[k + 1], idx[k + 2]], axis=1)   # fan


def _influences(doc: _Doc, attrs: dict, pw: str, V: int, skin_size: int):
    joints, weights = [], []
    s = 0
    while f"JOINTS_{s}" in attrs and f"WEIGHTS_{s}" in attrs:
        jw, ww = f"{pw}.attributes.JOINTS_{s}", f"{pw}.attributes.WEIGHTS_{s}"
        jj = np.asarray(doc.accessor(attrs[f"JOINTS_{s}"], jw, types=("VEC4",),
                                     components=(5121, 5123)))
        w = np.asarray(doc.accessor(attrs[f"WEIGHTS_{s}"], ww, types=("VEC4",),
                                    components=(5126, 5121, 5123)), dtype=float)
        for arr, where in ((jj, jw), (w, ww)):
            if len(arr) != V:
                raise doc.error(where, f"{len(arr)} values for {V} vertices")
        if np.any(w < 0):
            raise doc.error(ww, "negative skin weights")
        used = w > 0
        if np.any(jj[used] >= skin_size):
            bad = int(jj[used][jj[used] >= skin_size][0])
            raise doc.error(jw, f"joint index {bad}, but the skin has {skin_size} joints")
        jj = np.where(used, jj, 0)
        joints.append(jj)
        weights.append(w)
        s += 1
    return np.concatenate(joints, axis=1), np.concatenate(weights, axis=1)


# =========================================================================== writing
class _Builder:
    """Accumulates binary data and accessors for one buffer."""

    def __init__(self):
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, array: np.ndarray, ctype: int, typ: str, *, target: int | None = None,
            minmax: bool = False) -> int:
        dtype = _COMPONENTS[ctype]
        arr = np.ascontiguousarray(array, dtype=dtype)
        rows, cols = _TYPES[typ]
        count = arr.shape[0]
        if cols > 1:                                    # row-major (count, r, c) -> columns
            arr = np.ascontiguousarray(arr.transpose(0, 2, 1))
        while len(self.data) % 4:
            self.data.append(0)
        raw = arr.tobytes()
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.views.append(view)
        self.data.extend(raw)
        acc = {"bufferView": len(self.views) - 1, "componentType": ctype, "count": count,
               "type": typ}
        if minmax:
            flat = arr.reshape(count, -1).astype(float)
            acc["min"] = [float(x) for x in flat.min(axis=0)]
            acc["max"] = [float(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def write_gltf(motion: Motion, character: Character | None, path: str | os.PathLike, *,
               name: str | None = None) -> None:
    """Write ``motion`` on ``character`` as glTF 2.0, atomically.

    ``.glb`` (the default for any other suffix) is the binary container; ``.gltf`` is JSON with
    the buffer embedded as a ``data:`` URI. The file holds the character's meshes, one skin
    over every joint of ``motion.skeleton`` (the bind pose = its zero rotations, each joint's
    axes from :attr:`Character.bind_rotations`) and one animation named ``name`` (the motion's
    name by default): a rotation channel per joint and a translation channel per joint with
    position channels (the root at least), LINEAR, one key per frame. ``character`` may be
    ``None`` for a skeleton-only file (joint axes along the world's).

    Raises:
        ExportError: when the motion's skeleton is not the character's.
    """
    data = format_gltf(motion, character, name=name, binary=Path(path).suffix.lower() != ".gltf")
    atomic_write(path, data)


def _check_range(motion: Motion) -> None:
    """Refuse, with an :class:`ExportError`, a motion whose offsets or translations [m] leave
    the range the reader takes (:data:`engine.limits.MAX_MAGNITUDE`): the file would not read
    back."""
    sk = motion.skeleton
    if not limits.all_usable(sk.offsets):
        j = int(np.flatnonzero(~(np.abs(sk.offsets) <= limits.MAX_MAGNITUDE).all(axis=1))[0])
        raise ExportError(f"the offset of {sk.names[j]!r} ({sk.offsets[j].tolist()} m) is "
                          f"beyond the range a glTF file is read with (magnitude at most "
                          f"{limits.MAX_MAGNITUDE:g}); the file would not read back")
    if not limits.all_usable(motion.translations):
        f, k = (int(i[0]) for i in
                np.nonzero(~(np.abs(motion.translations) <= limits.MAX_MAGNITUDE).all(axis=2)))
        raise ExportError(f"frame {f + 1}: the translation of {sk.names[sk.translated[k]]!r} "
                          f"({motion.translations[f, k].tolist()} m) is beyond the range a glTF "
                          f"file is read with (magnitude at most {limits.MAX_MAGNITUDE:g}); the "
                          "file would not read back (a root scale that blows the motion up?)")


def format_gltf(motion: Motion, character: Character | None, *, name: str | None = None,
                binary: bool = True) -> bytes:
    """The bytes :func:`write_gltf` writes (GLB, or ``.gltf`` JSON when ``binary`` is off)."""
    sk = motion.skeleton
    J = sk.num_joints
    if motion.num_frames == 0:
        raise ExportError("the motion has no frames to write")
    if J > 65536:
        raise ExportError(f"{J} joints: glTF joint indices stop at 65535")
    _check_range(motion)
    if character is not None:
        check_fits(character, motion)
        bind_q = np.asarray(character.bind_rotations, dtype=float)
        meshes = character.meshes
    else:
        bind_q = np.zeros((J, 4))
        bind_q[:, 3] = 1.0
        meshes = ()
    parents = sk.parents
    rest = _rest_positions(sk)
    b = _Builder()

    # nodes: joints first (node j = joint j), then End Sites, then mesh nodes
    nodes: list[dict] = []
    parent_q = np.empty((J, 4))
    parent_q[0] = (0.0, 0.0, 0.0, 1.0)
    parent_q[1:] = bind_q[parents[1:]]
    node_q = qmul(qconj(parent_q), bind_q)
    node_t = qrot(qconj(parent_q), sk.offsets)
    for j in range(J):
        nodes.append({"name": sk.names[j], "translation": [float(x) for x in node_t[j]],
                      "rotation": [float(x) for x in node_q[j]]})
    for j in range(1, J):
        nodes[parents[j]].setdefault("children", []).append(j)
    for site in sk.end_sites:
        t = qrot(qconj(bind_q[site.parent]), site.offset)
        nodes.append({"name": site.name, "translation": [float(x) for x in t]})
        nodes[site.parent].setdefault("children", []).append(len(nodes) - 1)

    ibm = np.tile(np.eye(4), (J, 1, 1))
    rot_m = _quat_to_matrix(bind_q)
    ibm[:, :3, :3] = np.swapaxes(rot_m, 1, 2)
    ibm[:, :3, 3] = -np.einsum("jba,jb->ja", rot_m, rest)
    skin = {"joints": list(range(J)), "skeleton": 0,
            "inverseBindMatrices": b.add(ibm, 5126, "MAT4"),
            "name": character.name if character is not None else sk.names[0]}

    gl_meshes = []
    scene_nodes = [0]
    for m in meshes:
        attrs = {"POSITION": b.add(m.positions, 5126, "VEC3", target=34962, minmax=True)}
        if m.normals is not None:
            attrs["NORMAL"] = b.add(m.normals, 5126, "VEC3", target=34962)
        K = m.joints.shape[1]
        width = max(4, (K + 3) // 4 * 4)
        jj = np.zeros((m.num_vertices, width), dtype=np.int64)
        ww = np.zeros((m.num_vertices, width))
        jj[:, :K] = m.joints
        ww[:, :K] = m.weights
        ctype = 5121 if J <= 256 else 5123
        for s in range(width // 4):
            attrs[f"JOINTS_{s}"] = b.add(jj[:, 4 * s:4 * s + 4], ctype, "VEC4", target=34962)
            attrs[f"WEIGHTS_{s}"] = b.add(ww[:, 4 * s:4 * s + 4], 5126, "VEC4", target=34962)
        tris = np.asarray(m.triangles).reshape(-1)
        prim = {"attributes": attrs, "mode": 4}
        if len(tris):
            prim["indices"] = b.add(tris, 5125, "SCALAR", target=34963)
        gl_meshes.append({"name": m.name, "primitives": [prim]})
        nodes.append({"name": m.name, "mesh": len(gl_meshes) - 1, "skin": 0})
        scene_nodes.append(len(nodes) - 1)

    # the animation
    F = motion.num_frames
    times = np.arange(F) * motion.frame_time
    t_acc = b.add(times.astype(np.float32), 5126, "SCALAR", minmax=True)
    samplers, channels = [], []
    rot = motion.rotations
    gl_rot = qmul(qconj(parent_q)[None], qmul(rot, bind_q[None]))
    # neighbouring keys in one hemisphere, so that any slerp takes the short way
    dots = np.sum(gl_rot[1:] * gl_rot[:-1], axis=-1)
    signs = np.concatenate([np.ones((1, J)), np.cumprod(np.where(dots < 0, -1.0, 1.0),
                                                         axis=0)])
    gl_rot = gl_rot * signs[..., None]
    for j in range(J):
        samplers.append({"input": t_acc, "output": b.add(gl_rot[:, j], 5126, "VEC4"),
                         "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1,
                         "target": {"node": j, "path": "rotation"}})
    for k, j in enumerate(sk.translated):
        t = motion.translations[:, k]
        if j > 0:
            t = qrot(qconj(parent_q[j])[None], t)
        samplers.append({"input": t_acc, "output": b.add(t, 5126, "VEC3"),
                         "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1,
                         "target": {"node": int(j), "path": "translation"}})
    anim_name = name if name is not None else (motion.name or "motion")

    moving = [sk.names[j] for j in sk.translated]
    js = {
        "asset": {"version": "2.0", "generator": "Motion Composer",
                  "extras": {_EXTRAS_KEY: {"positionChannels": moving,
                                           "fps": motion.fps}}},
        "scene": 0,
        "scenes": [{"nodes": scene_nodes}],
        "nodes": nodes,
        "skins": [skin],
        "animations": [{"name": anim_name, "samplers": samplers, "channels": channels}],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.data)}],
    }
    if gl_meshes:
        js["meshes"] = gl_meshes
    while len(b.data) % 4:
        b.data.append(0)
    js["buffers"][0]["byteLength"] = len(b.data)
    if not binary:
        js["buffers"][0]["uri"] = ("data:application/octet-stream;base64," +
                                   base64.b64encode(bytes(b.data)).decode("ascii"))
        return (json.dumps(js, indent=1) + "\n").encode("utf-8")
    text = json.dumps(js, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    body = bytes(b.data)
    total = 12 + 8 + len(text) + 8 + len(body)
    return b"".join([struct.pack("<4sII", _GLB_MAGIC, 2, total),
                     struct.pack("<II", len(text), _CHUNK_JSON), text,
                     struct.pack("<II", len(body), _CHUNK_BIN), body])

