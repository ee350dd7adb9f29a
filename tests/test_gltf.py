"""glTF characters: reading, skinning, writing, errors, the CLI, and Blender as a second reader.

The checks that do not trust our own reader:

* a minimal GLB parser written here (``_Mini``: JSON + buffers + plain accessor reads + node
  matrices + per-channel key interpolation) evaluates the glTF skinning equation
  ``v' = sum w_k * world_k * inverseBind_k * v`` straight from the file, and our skinned
  meshes (reader + motion + :mod:`engine.skinning`) must land on it;
* Blender 3.4's own glTF importer loads the original data files and our written ones, and its
  pose-bone heads must sit where our forward kinematics puts the joints; its BVH importer
  loads our BVH of a glTF character likewise.

Synthetic characters are built by hand here (``_Glb``), independent of the engine's writer.
The checks on real characters run on the data files of ``../shared`` and on the bundled test
character, ``tests/data/test_character.glb`` (made by ``tests/data/make_test_character.py``
with our writer; the independent reader and Blender check it), so that a fresh clone tests
glTF reading, skinning and writing too.
"""
from __future__ import annotations

import base64
import json
import struct
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blender_util import blender_or_skip, run_blender
from conftest import clip_path, shared_path
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.formats.bvh import read_bvh, write_bvh
from motion_composer.engine.errors import FileFormatError, GLTFError, MotionComposerError
from motion_composer.engine.formats.gltf import Character, read_gltf, write_gltf
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.conversion import retarget
from motion_composer.engine.skinning import joint_matrices, skin_character, skin_vertices

ROBOT = "target_robot_expressive.glb"
FOX = "target_fox.glb"
#: the bundled test character (tests/data), and its animation
TEST_CHARACTER = "test_character.glb"
SWING = "Swing"
TEST_DATA = Path(__file__).resolve().parent / "data"
ROBOT_JOINTS = (
    "Bone FootL Body Hips Abdomen Torso_1 Neck Head ShoulderL UpperArmL LowerArmL Palm2L "
    "Middle1L Middle2L ThumbL Thumb2L Palm1L IndexL Index2L Palm3L Ring1L Ring2L ShoulderR "
    "UpperArmR LowerArmR Palm2R Middle1R Middle2R ThumbR Thumb2R Palm1R IndexR Index2R Palm3R "
    "Ring1R Ring2R UpperLegL LowerLegL UpperLegR LowerLegR PoleTargetL FootR PoleTargetR"
).split()
FOX_JOINTS = (
    "_rootJoint b_Root_00 b_Hip_01 b_Spine01_02 b_Spine02_03 b_Neck_04 b_Head_05 "
    "b_RightUpperArm_06 b_RightForeArm_07 b_RightHand_08 b_LeftUpperArm_09 b_LeftForeArm_010 "
    "b_LeftHand_011 b_Tail01_012 b_Tail02_013 b_Tail03_014 b_LeftLeg01_015 b_LeftLeg02_016 "
    "b_LeftFoot01_017 b_LeftFoot02_018 b_RightLeg01_019 b_RightLeg02_020 b_RightFoot01_021 "
    "b_RightFoot02_022"
).split()


# =========================================================================== helpers
def character_path(name: str) -> Path:
    """The bundled test character in tests/data, or a data file of ../shared (or skip)."""
    return TEST_DATA / name if name == TEST_CHARACTER else shared_path(name)


def _size(character: Character) -> float:
    return float(np.ptp(character.bind_positions, axis=0).max())


def _same_rotations(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle [rad] between two quaternion arrays (sign-blind)."""
    d = np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)
    return float(2 * np.arccos(d).max()) if d.size else 0.0


def _trs(t=(0, 0, 0), q=(0, 0, 0, 1), s=(1, 1, 1)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix() * np.asarray(s, float)
    m[:3, 3] = t
    return m


class _Mini:
    """A deliberately small GLB reader for cross-checks: no validation, plain loops."""

    SIZES = {5120: ("b", 1), 5121: ("B", 1), 5122: ("h", 2), 5123: ("H", 2), 5125: ("I", 4),
             5126: ("f", 4)}
    WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def __init__(self, path):
        data = Path(path).read_bytes()
        jlen = struct.unpack_from("<I", data, 12)[0]
        self.js = json.loads(data[20:20 + jlen])
        blen = struct.unpack_from("<I", data, 20 + jlen)[0]
        self.bin = data[28 + jlen:28 + jlen + blen]
        self.nodes = self.js["nodes"]
        self.parent = {c: i for i, n in enumerate(self.nodes) for c in n.get("children", [])}

    def acc(self, i) -> np.ndarray:
        a = self.js["accessors"][i]
        bv = self.js["bufferViews"][a["bufferView"]]
        fmt, size = self.SIZES[a["componentType"]]
        n = self.WIDTH[a["type"]]
        stride = bv.get("byteStride", size * n)
        base = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
        rows = [struct.unpack_from("<" + fmt * n, self.bin, base + k * stride)
                for k in range(a["count"])]
        out = np.array(rows, dtype=float)
        if a.get("normalized"):
            out /= {5121: 255.0, 5123: 65535.0}[a["componentType"]]
        if a["type"] == "MAT4":
            out = out.reshape(-1, 4, 4).transpose(0, 2, 1)
        return out

    def local(self, i, overrides=None) -> np.ndarray:
        n = self.nodes[i]
        if "matrix" in n:
            return np.array(n["matrix"], float).reshape(4, 4).T
        trs = {"translation": n.get("translation", [0, 0, 0]),
               "rotation": n.get("rotation", [0, 0, 0, 1]), "scale": n.get("scale", [1, 1, 1])}
        trs.update((overrides or {}).get(i, {}))
        return _trs(trs["translation"], trs["rotation"], trs["scale"])

    def world(self, i, overrides=None) -> np.ndarray:
        m = self.local(i, overrides)
        while i in self.parent:
            i = self.parent[i]
            m = self.local(i, overrides) @ m
        return m

    def pose_at(self, animation: int, time: float) -> dict:
        """Node TRS overrides at ``time`` (LINEAR keys: lerp, shortest slerp)."""
        anim = self.js["animations"][animation]
        out: dict = {}
        for ch in anim["channels"]:
            path = ch["target"]["path"]
            if path == "weights":
                continue
            sampler = anim["samplers"][ch["sampler"]]
            assert sampler.get("interpolation", "LINEAR") == "LINEAR"
            t = self.acc(sampler["input"])[:, 0]
            v = self.acc(sampler["output"])
            k = max(0, min(int(np.searchsorted(t, time, side="right")) - 1, len(t) - 1))
            if k == len(t) - 1 or time <= t[0]:
                value = v[k if time > t[0] else 0]
            else:
                u = (time - t[k]) / (t[k + 1] - t[k])
                a, b = v[k], v[k + 1]
                if path == "rotation":
                    if np.dot(a, b) < 0:
                        b = -b
                    value = Rotation.from_quat([a, b])
                    from scipy.spatial.transform import Slerp
                    value = Slerp([0, 1], value)(u).as_quat()
                else:
                    value = a + (b - a) * u
            out.setdefault(ch["target"]["node"], {})[path] = list(value)
        return out

    def skinned_world_vertices(self, overrides=None) -> list[np.ndarray]:
        """Every mesh primitive as glTF defines it in the world, in node order: skinned
        primitives by the skinning equation, others by their node's world matrix."""
        out = []
        order = []
        stack = [i for i in range(len(self.nodes)) if i not in self.parent][::-1]
        while stack:
            i = stack.pop()
            order.append(i)
            stack.extend(self.nodes[i].get("children", [])[::-1])
        for i in order:
            node = self.nodes[i]
            if "mesh" not in node:
                continue
            for prim in self.js["meshes"][node["mesh"]]["primitives"]:
                v = self.acc(prim["attributes"]["POSITION"])
                vh = np.concatenate([v, np.ones((len(v), 1))], axis=1)
                if "skin" in node:
                    skin = self.js["skins"][node["skin"]]
                    ibm = self.acc(skin["inverseBindMatrices"])
                    mats = [self.world(j, overrides) @ ibm[k]
                            for k, j in enumerate(skin["joints"])]
                    jj = self.acc(prim["attributes"]["JOINTS_0"]).astype(int)
                    ww = self.acc(prim["attributes"]["WEIGHTS_0"])
                    ww = ww / ww.sum(axis=1, keepdims=True)
                    res = np.zeros((len(v), 3))
                    for vi in range(len(v)):
                        m = sum(ww[vi, k] * mats[jj[vi, k]] for k in range(4))
                        res[vi] = (m @ vh[vi])[:3]
                else:
                    res = (vh @ self.world(i, overrides).T)[:, :3]
                out.append(res)
        return out


class _Glb:
    """Build small glTF files by hand (independent of the engine's writer)."""

    def __init__(self):
        self.bin = bytearray()
        self.js = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": [],
                   "buffers": [], "nodes": []}

    def view(self, raw: bytes, stride: int | None = None) -> int:
        while len(self.bin) % 4:
            self.bin.append(0)
        bv = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(raw)}
        if stride:
            bv["byteStride"] = stride
        self.js["bufferViews"].append(bv)
        self.bin.extend(raw)
        return len(self.js["bufferViews"]) - 1

    def acc(self, array, ctype: int, typ: str, **extra) -> int:
        dt = {5121: "<u1", 5123: "<u2", 5125: "<u4", 5126: "<f4"}[ctype]
        arr = np.asarray(array)
        if typ == "MAT4":
            arr = arr.transpose(0, 2, 1)
        arr = np.ascontiguousarray(arr, dtype=dt)
        a = {"bufferView": self.view(arr.tobytes()), "componentType": ctype,
             "count": int(arr.shape[0]), "type": typ}
        a.update(extra)
        self.js["accessors"].append(a)
        return len(self.js["accessors"]) - 1

    def node(self, **fields) -> int:
        self.js["nodes"].append({k: v for k, v in fields.items() if v is not None})
        return len(self.js["nodes"]) - 1

    def glb(self) -> bytes:
        js = json.loads(json.dumps(self.js))
        js["buffers"] = [{"byteLength": len(self.bin)}]
        return pack_glb(js, bytes(self.bin))

    def write(self, path: Path) -> Path:
        path.write_bytes(self.glb())
        return path


def pack_glb(js: dict, binary: bytes) -> bytes:
    text = json.dumps(js).encode()
    text += b" " * (-len(text) % 4)
    binary = binary + b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(text), 0x4E4F534A)
            + text + struct.pack("<II", len(binary), 0x004E4942) + binary)


def unpack_glb(data: bytes) -> tuple[dict, bytes]:
    jlen = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + jlen])
    blen = struct.unpack_from("<I", data, 20 + jlen)[0]
    return js, data[28 + jlen:28 + jlen + blen]


def chain_character(tmp_path: Path, *, armature=None, names=True, ibm_space="world",
                    animate=True, name="chain.glb", extra_ibm_scale=None) -> tuple[Path, dict]:
    """A three-joint chain (hip, spine, head) authored Z-up in centimetres, under an optional
    non-joint ``armature`` node (a 4x4 matrix given as TRS), with a skinned quad strip and a
    LINEAR animation keyed at 30 fps. ``ibm_space``: "world" (IBMs include the armature) or
    "armature" (three.js style: relative to it). Returns the path and the expected world
    (default) joint positions and mesh vertices."""
    g = _Glb()
    arm = armature or {}
    a = g.node(name="Armature" if names else None, children=[1], **arm)
    j0 = g.node(name="hip" if names else None, translation=[0.0, 10.0, 100.0], children=[2])
    j1 = g.node(name="spine" if names else None, translation=[0.0, 0.0, 50.0],
                rotation=list(Rotation.from_euler("x", 20, degrees=True).as_quat()),
                children=[3])
    j2 = g.node(name="head" if names else None, translation=[0.0, 0.0, 50.0])
    joints = [j0, j1, j2]
    keys = {"translation": "t", "rotation": "q", "scale": "s"}
    locals_ = {i: _trs(**{keys[k]: v for k, v in g.js["nodes"][i].items() if k in keys})
               for i in joints + [a]}
    A = locals_[a]
    world = {j0: A @ locals_[j0]}
    world[j1] = world[j0] @ locals_[j1]
    world[j2] = world[j1] @ locals_[j2]
    space = {j: (world[j] if ibm_space == "world" else np.linalg.inv(A) @ world[j])
             for j in joints}
    ibm = np.array([np.linalg.inv(space[j]) for j in joints])
    if extra_ibm_scale is not None:
        ibm[1] = np.diag(list(extra_ibm_scale) + [1.0]) @ ibm[1]
    ibm_acc = g.acc(ibm, 5126, "MAT4")
    # vertices: a strip around the chain, authored in the IBM space
    pts_world = []
    for j in joints:
        p = world[j][:3, 3]
        pts_world += [p + (world[j][:3, :3] @ np.array([s * 20.0, 0.0, 0.0])) for s in (-1, 1)]
    pts_world = np.array(pts_world)
    to_space = np.eye(4) if ibm_space == "world" else np.linalg.inv(A)
    verts = (np.c_[pts_world, np.ones(len(pts_world))] @ to_space.T)[:, :3]
    pos = g.acc(verts, 5126, "VEC3", min=list(verts.min(0)), max=list(verts.max(0)))
    jj = np.array([[0, 1, 0, 0], [0, 1, 0, 0], [1, 2, 0, 0], [1, 2, 0, 0], [2, 0, 0, 0],
                   [2, 0, 0, 0]])
    ww = np.array([[0.7, 0.3, 0, 0], [0.7, 0.3, 0, 0], [0.5, 0.5, 0, 0], [0.5, 0.5, 0, 0],
                   [1, 0, 0, 0], [1, 0, 0, 0]])
    joints_acc = g.acc(jj, 5121, "VEC4")
    weights_acc = g.acc(ww, 5126, "VEC4")
    tri = g.acc(np.array([0, 1, 2, 2, 1, 3, 2, 3, 4, 4, 3, 5]), 5125, "SCALAR")
    g.js["meshes"] = [{"name": "strip", "primitives": [{
        "attributes": {"POSITION": pos, "JOINTS_0": joints_acc, "WEIGHTS_0": weights_acc},
        "indices": tri}]}]
    mesh_node = g.node(name="body" if names else None, mesh=0, skin=0)
    g.js["skins"] = [{"joints": joints, "inverseBindMatrices": ibm_acc}]
    g.js["scenes"] = [{"nodes": [a, mesh_node]}]
    g.js["scene"] = 0
    if animate:
        t = g.acc(np.array([0.0, 0.5, 1.0]), 5126, "SCALAR", min=[0.0], max=[1.0])
        rots = Rotation.from_euler("x", [[20], [60], [-10]], degrees=True).as_quat()
        rot = g.acc(rots, 5126, "VEC4")
        tr = g.acc(np.array([[0, 10, 100], [30, 10, 95], [60, 10, 100.0]]), 5126, "VEC3")
        g.js["animations"] = [{"name": "bend", "samplers": [
            {"input": t, "output": rot}, {"input": t, "output": tr}], "channels": [
            {"sampler": 0, "target": {"node": j1, "path": "rotation"}},
            {"sampler": 1, "target": {"node": j0, "path": "translation"}}]}]
    path = g.write(tmp_path / name)
    expect = {"joints": np.array([world[j][:3, 3] for j in joints]), "vertices": pts_world,
              "world": world, "A": A}
    return path, expect


# =========================================================================== the data files
@pytest.fixture(scope="module")
def robot() -> Character:
    return read_gltf(shared_path(ROBOT))


@pytest.fixture(scope="module")
def fox() -> Character:
    return read_gltf(shared_path(FOX))


def test_robot_loads(robot):
    sk = robot.skeleton
    assert sk.num_joints == 43
    assert set(sk.names) == set(ROBOT_JOINTS)
    assert len(robot.skins) == 4 and len(robot.skin_joints) == 4
    assert all(sorted(m.tolist()) == list(range(43)) for m in robot.skin_joints)
    # IK bones hang from the root joint, not from the legs
    for name in ("FootL", "FootR", "PoleTargetL", "PoleTargetR"):
        assert sk.names[sk.parents[sk.index[name]]] == "Bone"
    assert sk.names[sk.parents[sk.index["LowerLegL"]]] == "UpperLegL"
    assert [m.name for m in robot.motions] == [
        "Dance", "Death", "Idle", "Jump", "No", "Punch", "Running", "Sitting", "Standing",
        "ThumbsUp", "Walking", "WalkJump", "Wave", "Yes"]
    durations = {m.name: m.duration for m in robot.motions}
    assert durations["Dance"] == pytest.approx(3.33, abs=0.02)
    assert durations["Sitting"] == pytest.approx(0.42, abs=0.034)
    assert all(m.fps == 30.0 for m in robot.motions)
    # four skinned hand meshes plus the rigid body parts hanging under joint nodes
    assert sum(m.skin is not None for m in robot.meshes) == 4
    assert sum(m.skin is None for m in robot.meshes) == 15
    assert sk.source.units == "m" and sk.source.up_axis == "+Y"
    # every joint can be written to BVH: rotations everywhere, positions where they move
    assert all(ch[-3:] == ("Zrotation", "Xrotation", "Yrotation") for ch in sk.channels)
    moving = {sk.names[j] for j in sk.translated}
    assert {"Bone", "Body", "FootL", "FootR"} <= moving and "Hips" not in moving


def test_robot_z_up_bind_becomes_y_up_metres(robot):
    """The bind pose is authored Z-up at 0.01 scale under a node turning it Y-up at 100x: the
    skeleton stands up along +Y about 3 units tall, as the README measures (head y=2.98 in the
    scene's default pose; the bind T-pose stands a little straighter)."""
    sk = robot.skeleton
    head = sk.index["Head"]
    default = forward_kinematics(robot.node_pose).positions[0]
    assert default[head, 1] == pytest.approx(2.98, abs=0.01)
    bind = robot.bind_positions
    assert bind[head, 1] == pytest.approx(3.04, abs=0.02)
    feet = bind[[sk.index["FootL"], sk.index["FootR"]], 1]
    assert np.all(np.abs(feet) < 0.05)                    # feet on the floor
    hand_l, hand_r = bind[sk.index["Palm2L"]], bind[sk.index["Palm2R"]]
    assert abs(hand_l[0] - hand_r[0]) > 4.0 and abs(hand_l[1] - 2.45) < 0.1   # a T-pose
    # rest_motion is the bind pose, and the robot's own walk keeps its ankles near the floor
    fk = forward_kinematics(robot.rest_motion()).positions[0]
    np.testing.assert_allclose(fk, bind, atol=1e-12)
    walk = forward_kinematics(robot.motion("Walking"))
    ends = {s.name: k for k, s in enumerate(sk.end_sites)}
    ankle = walk.end_positions[:, ends["LowerLegL_end"], 1]
    assert ankle.min() > 0.0 and ankle.min() < 0.1 and ankle.max() < 0.7


def test_fox_loads(fox):
    sk = fox.skeleton
    assert sk.num_joints == 24 and list(sk.names) == FOX_JOINTS
    assert sk.names[sk.parents[1]] == "_rootJoint"
    assert [m.name for m in fox.motions] == ["Survey", "Walk", "Run"]
    assert len(fox.meshes) == 1 and fox.meshes[0].num_vertices == 1728
    head = fox.bind_positions[sk.index["b_Head_05"]]
    hips = fox.bind_positions[sk.index["b_Hip_01"]]
    assert head[1] == pytest.approx(60.7, abs=0.1) and hips[1] == pytest.approx(42.9, abs=0.1)
    assert any("centimetres" in note for note in fox.notes)


@pytest.mark.parametrize("name", [ROBOT, FOX, TEST_CHARACTER])
def test_bind_pose_reproduces_inverse_bind_matrices(name):
    """Each joint's bind matrix F_s * inverse(IBM) (F_s placing skin s's bind space so that its
    top joint sits where the scene puts it, computed here independently) equals the
    skeleton's bind position, and its rotation/scale the character's bind rotation/scale."""
    path = character_path(name)
    character = read_gltf(path)
    mini = _Mini(path)
    size = _size(character)
    bind = character.bind_positions
    for s, skin_index in enumerate(character.skins):
        skin = mini.js["skins"][skin_index]
        ibm = mini.acc(skin["inverseBindMatrices"])
        depth = [len(_ancestors(mini, n)) for n in skin["joints"]]
        top = int(np.argmin(depth))
        frame = mini.world(skin["joints"][top]) @ ibm[top]
        np.testing.assert_allclose(character.skin_frames[s], frame, atol=1e-9 * size)
        for k, node in enumerate(skin["joints"]):
            j = int(character.skin_joints[s][k])
            assert character.node_indices[j] == node
            m = frame @ np.linalg.inv(ibm[k])
            np.testing.assert_allclose(bind[j], m[:3, 3], atol=1e-9 * size, rtol=0)
            rot = Rotation.from_quat(character.bind_rotations[j]).as_matrix()
            np.testing.assert_allclose(rot * character.bind_scales[j], m[:3, :3],
                                       atol=1e-5 * character.bind_scales[j])
    if name == FOX:     # no node above the skeleton: the bind space is the world
        np.testing.assert_allclose(character.skin_frames[0], np.eye(4), atol=1e-9)


def _ancestors(mini: _Mini, n: int) -> list[int]:
    out = []
    while n in mini.parent:
        n = mini.parent[n]
        out.append(n)
    return out


@pytest.mark.parametrize("name", [ROBOT, FOX, TEST_CHARACTER])
def test_skinning_bind_pose_gives_bind_vertices(name):
    character = read_gltf(character_path(name))
    for mesh, verts in zip(character.meshes, skin_character(character)):
        assert verts.shape == (1, mesh.num_vertices, 3)
        np.testing.assert_allclose(verts[0], mesh.positions, atol=1e-6, rtol=0)


@pytest.mark.parametrize("name,animation,frames", [(ROBOT, "Walking", [0, 7, 20]),
                                                   (FOX, "Walk", [0, 9, 22]),
                                                   (TEST_CHARACTER, SWING, [0, 7, 22])])
def test_posed_mesh_matches_gltf_skinning_equation(name, animation, frames):
    """Our skinned vertices at animated frames equal the glTF equation evaluated from the file
    by the small independent reader (skinned primitives: sum w * world * IBM * v; rigid parts:
    their node's world matrix)."""
    path = character_path(name)
    character = read_gltf(path)
    mini = _Mini(path)
    motion = character.motion(animation)
    a = [an["name"] for an in mini.js["animations"]].index(animation)
    size = _size(character)
    ours = skin_character(character, motion, frames=frames)
    for k, f in enumerate(frames):
        overrides = mini.pose_at(a, f * motion.frame_time)
        reference = mini.skinned_world_vertices(overrides)
        assert len(reference) == len(character.meshes)
        for mesh, verts, ref in zip(character.meshes, ours, reference):
            err = np.abs(verts[k] - ref).max()
            assert err < 1e-5 * size, (mesh.name, f, err)


def test_vectorised_skinning_matches_a_per_vertex_loop(robot):
    motion = robot.motion("Punch")
    pose = forward_kinematics(motion.frames([3, 11]), end_sites=False)
    mats = joint_matrices(pose.rotations, pose.positions, robot.bind_positions)
    mesh = next(m for m in robot.meshes if m.skin is not None)
    fast = skin_vertices(mesh.positions, mesh.joints, mesh.weights, mats)
    bind = robot.bind_positions
    for f in range(2):
        rot = Rotation.from_quat(pose.rotations[f])
        for v in range(0, mesh.num_vertices, 7):
            expect = np.zeros(3)
            for j, w in zip(mesh.joints[v], mesh.weights[v]):
                expect += w * (rot[j].apply(mesh.positions[v] - bind[j]) + pose.positions[f, j])
            np.testing.assert_allclose(fast[f, v], expect, atol=1e-12)


# =========================================================================== synthetic files
@pytest.mark.parametrize("ibm_space", ["world", "armature"])
def test_z_up_bind_under_rotated_scaled_root(tmp_path, ibm_space):
    """Joints authored Z-up in centimetres under a non-joint root turning them Y-up at 0.01
    scale: the skeleton is Y-up metres, whether the inverse bind matrices include that root
    (Blender-like) or are relative to it (three.js-like, as in Robot Expressive)."""
    root = {"rotation": list(Rotation.from_euler("x", -90, degrees=True).as_quat()),
            "scale": [0.01, 0.01, 0.01]}
    path, expect = chain_character(tmp_path, armature=root, ibm_space=ibm_space)
    c = read_gltf(path)
    sk = c.skeleton
    assert sk.names == ("hip", "spine", "head")
    np.testing.assert_allclose(c.bind_positions, expect["joints"], atol=1e-6)
    np.testing.assert_allclose(c.bind_positions[0], [0, 1.0, -0.1], atol=1e-6)   # Z-up -> Y
    assert np.linalg.norm(sk.offsets[1]) == pytest.approx(0.5)                    # cm -> m
    np.testing.assert_allclose(c.meshes[0].positions, expect["vertices"], atol=1e-6)
    np.testing.assert_allclose(c.bind_scales, 0.01, rtol=1e-6)
    _check_animation_against_nodes(c, expect)


def test_root_with_uniform_scale(tmp_path):
    path, expect = chain_character(tmp_path, armature={"scale": [0.01, 0.01, 0.01],
                                                       "translation": [1.0, 0.0, 0.0]})
    c = read_gltf(path)
    np.testing.assert_allclose(c.bind_positions, expect["joints"], atol=1e-6)
    np.testing.assert_allclose(c.skeleton.offsets[1], [0, 0, 0.5], atol=1e-6)
    np.testing.assert_allclose(c.meshes[0].positions, expect["vertices"], atol=1e-6)
    _check_animation_against_nodes(c, expect)


def _check_animation_against_nodes(c: Character, expect: dict) -> None:
    """The animation keyed at 0, 0.5 and 1 s: our frames 0, 15 and 30 put the joints where the
    node hierarchy does at those times."""
    motion = c.motions[0]
    assert motion.num_frames == 31 and motion.name == "bend"
    pos = forward_kinematics(motion).positions
    A = expect["A"]
    keys = [(0, [0, 10, 100], 20), (15, [30, 10, 95], 60), (30, [60, 10, 100], -10)]
    for frame, hip, angle in keys:
        w0 = A @ _trs(hip)
        w1 = w0 @ _trs([0, 0, 50], Rotation.from_euler("x", angle, degrees=True).as_quat())
        w2 = w1 @ _trs([0, 0, 50])
        np.testing.assert_allclose(pos[frame], [w0[:3, 3], w1[:3, 3], w2[:3, 3]], atol=1e-6)
    # skinning the animated frame equals the skinning equation with these node matrices
    verts = skin_character(c, motion, frames=[15])[0][0]
    assert np.all(np.isfinite(verts))


def test_unnamed_joints_are_named_by_node_index(tmp_path):
    path, _ = chain_character(tmp_path, names=False, armature={"translation": [0, 0, 0]})
    c = read_gltf(path)
    assert c.skeleton.names == ("joint_1", "joint_2", "joint_3")
    assert any("without a name" in note for note in c.notes)
    assert c.meshes[0].name == "strip"


def test_skin_without_inverse_bind_matrices(tmp_path):
    """No inverseBindMatrices means identity matrices: each vertex is authored in its joints'
    spaces, and the default node pose is the bind pose."""
    path, expect = chain_character(tmp_path, armature={"translation": [0.0, 0.0, 0.0]})
    js, binary = unpack_glb(path.read_bytes())
    del js["skins"][0]["inverseBindMatrices"]
    (tmp_path / "no_ibm.glb").write_bytes(pack_glb(js, binary))
    c = read_gltf(tmp_path / "no_ibm.glb")
    assert any("no inverse bind matrices" in note for note in c.notes)
    np.testing.assert_allclose(c.bind_positions, expect["joints"], atol=1e-6)
    mini = _Mini(tmp_path / "no_ibm.glb")
    prim = mini.js["meshes"][0]["primitives"][0]["attributes"]
    v = mini.acc(prim["POSITION"])
    jj = mini.acc(prim["JOINTS_0"]).astype(int)
    ww = mini.acc(prim["WEIGHTS_0"])
    worlds = [mini.world(n) for n in (1, 2, 3)]
    expect_v = [sum(ww[i, k] * (worlds[jj[i, k]] @ np.r_[v[i], 1.0])[:3] for k in range(4))
                for i in range(len(v))]
    np.testing.assert_allclose(c.meshes[0].positions, expect_v, atol=1e-6)


def test_non_uniform_bind_scale_is_refused(tmp_path):
    path, _ = chain_character(tmp_path, extra_ibm_scale=(1.0, 2.0, 1.0))
    with pytest.raises(GLTFError) as info:
        read_gltf(path)
    assert info.value.where == "skins[0].inverseBindMatrices"
    assert "non-uniform" in str(info.value) and "spine" in str(info.value)
    assert str(path) in str(info.value)


def test_two_skins_two_roots_sparse_strided_normalized(tmp_path):
    """Two skins sharing one joint and each with a root of its own (joined under their common
    non-joint ancestor); a sparse POSITION accessor over an interleaved (strided) buffer view;
    UNSIGNED_BYTE normalized weights that do not sum to 1 (normalised, with a note); a STEP
    translation and a CUBICSPLINE rotation sampled between keys."""
    g = _Glb()
    top = g.node(name="rig", children=[1, 3], translation=[0.0, 1.0, 0.0])
    a0 = g.node(name="a0", children=[2])
    a1 = g.node(name="a1", translation=[0.0, 0.5, 0.0])
    b0 = g.node(name="b0", translation=[1.0, 0.0, 0.0], children=[4])
    b1 = g.node(name="b1", translation=[0.0, 0.5, 0.0])
    world = {a0: _trs([0, 1, 0]), a1: _trs([0, 1.5, 0]), b0: _trs([1, 1, 0]),
             b1: _trs([1, 1.5, 0])}
    skins = [[a0, a1, b1], [b0, b1]]
    for joints in skins:
        ibm = g.acc(np.array([np.linalg.inv(world[j]) for j in joints]), 5126, "MAT4")
        g.js.setdefault("skins", []).append({"joints": joints, "inverseBindMatrices": ibm})
    # interleaved POSITION + NORMAL (stride 24), POSITION patched by a sparse accessor
    verts = np.array([[0, 1, 0], [0, 1.5, 0], [1, 1, 0], [1, 1.5, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    inter = np.concatenate([verts, normals], axis=1).astype("<f4").tobytes()
    bv = g.view(inter, stride=24)
    sparse_idx = g.view(np.array([3], "<u2").tobytes())
    sparse_val = g.view(np.array([[1.0, 1.6, 0.0]], "<f4").tobytes())
    g.js["accessors"] += [
        {"bufferView": bv, "componentType": 5126, "count": 4, "type": "VEC3",
         "min": [0, 1, 0], "max": [1, 1.6, 0],
         "sparse": {"count": 1, "indices": {"bufferView": sparse_idx, "componentType": 5123},
                    "values": {"bufferView": sparse_val}}},
        {"bufferView": bv, "byteOffset": 12, "componentType": 5126, "count": 4,
         "type": "VEC3"}]
    pos_acc, nrm_acc = len(g.js["accessors"]) - 2, len(g.js["accessors"]) - 1
    jj = g.acc(np.array([[0, 1, 0, 0]] * 2 + [[0, 1, 0, 0]] * 2), 5121, "VEC4")
    ww = g.acc(np.array([[128, 64, 0, 0], [255, 0, 0, 0], [100, 100, 0, 0], [0, 255, 0, 0]]),
               5121, "VEC4", normalized=True)
    tri = g.acc(np.array([0, 1, 2, 2, 1, 3]), 5123, "SCALAR")
    g.js["meshes"] = [{"primitives": [{"attributes": {"POSITION": pos_acc, "NORMAL": nrm_acc,
                                                      "JOINTS_0": jj, "WEIGHTS_0": ww},
                                       "indices": tri}]}]
    mesh_node = g.node(name="skinned", mesh=0, skin=1)
    t = g.acc(np.array([0.0, 1.0]), 5126, "SCALAR")
    step = g.acc(np.array([[0, 0.5, 0], [0, 0.9, 0.0]]), 5126, "VEC3")
    q0 = [0, 0, 0, 1.0]
    q1 = list(Rotation.from_euler("z", 90, degrees=True).as_quat())
    zero = [0, 0, 0, 0.0]
    cubic = g.acc(np.array([zero, q0, zero, zero, q1, zero]), 5126, "VEC4")
    g.js["animations"] = [{"name": "mix", "samplers": [
        {"input": t, "output": step, "interpolation": "STEP"},
        {"input": t, "output": cubic, "interpolation": "CUBICSPLINE"}], "channels": [
        {"sampler": 0, "target": {"node": a1, "path": "translation"}},
        {"sampler": 1, "target": {"node": a0, "path": "rotation"}}]}]
    g.js["scenes"] = [{"nodes": [top, mesh_node]}]
    path = g.write(tmp_path / "mixed.glb")

    c = read_gltf(path, fps=4)
    sk = c.skeleton
    assert sk.names == ("rig", "a0", "a1", "b0", "b1")
    assert [sk.names[p] if p >= 0 else None for p in sk.parents] == [None, "rig", "a0", "rig",
                                                                     "b0"]
    assert any("common ancestor" in note for note in c.notes)
    assert [list(m) for m in c.skin_joints] == [[1, 2, 4], [3, 4]]
    mesh = c.meshes[0]
    assert mesh.skin == 1
    np.testing.assert_allclose(mesh.positions, [[0, 1, 0], [0, 1.5, 0], [1, 1, 0],
                                                [1, 1.6, 0]], atol=1e-7)
    np.testing.assert_allclose(mesh.normals, normals)
    np.testing.assert_allclose(mesh.weights.sum(axis=1), 1.0)
    np.testing.assert_allclose(mesh.weights[0, :2], [2 / 3, 1 / 3], atol=1e-3)
    assert mesh.joints[0, 0] == 3 and mesh.joints[0, 1] == 4      # skin 1: b0, b1
    assert any("normalised" in note for note in c.notes)
    # one skin only: its joints (b1 without its parent b0 joins a0 under 'rig')
    only = read_gltf(path, skin=0, fps=4)
    assert only.skeleton.names == ("rig", "a0", "a1", "b1") and only.meshes == ()
    assert any("bound to other skins" in note for note in only.notes)
    np.testing.assert_allclose(only.bind_positions[3], [1, 1.5, 0], atol=1e-7)
    with pytest.raises(GLTFError, match="no skin 'hands'"):
        read_gltf(path, skin="hands")
    motion = c.motions[0]
    assert motion.num_frames == 5
    # STEP: the first key's value until the next key
    slot = list(sk.translated).index(2)
    np.testing.assert_allclose(motion.translations[:4, slot], [[0, 0.5, 0]] * 4, atol=1e-7)
    np.testing.assert_allclose(motion.translations[4, slot], [0, 0.9, 0], atol=1e-7)
    # CUBICSPLINE with zero tangents: Hermite h01(s) = 3s^2 - 2s^3 between the keys, normalised
    for f in range(5):
        s = f / 4
        blend = (1 - (3 * s * s - 2 * s ** 3)) * np.array(q0) + (3 * s * s - 2 * s ** 3) * \
            np.array(q1)
        blend /= np.linalg.norm(blend)
        assert _same_rotations(motion.rotations[f, 1], blend) < 1e-6


# =========================================================================== malformed files
def _valid(tmp_path) -> tuple[dict, bytes]:
    path, _ = chain_character(tmp_path, name="valid.glb")
    read_gltf(path)
    return unpack_glb(path.read_bytes())


def test_malformed_files_raise_typed_errors(tmp_path):
    js, binary = _valid(tmp_path)
    good = pack_glb(js, binary)
    cases = {}
    cases["truncated.glb"] = (good[:-40], "GLB header", "truncated")
    cases["magic.glb"] = (b"glTX" + good[4:], "GLB header", "magic")
    bad_chunk = bytearray(good)
    struct.pack_into("<I", bad_chunk, 12, len(good))
    cases["chunk.glb"] = (bytes(bad_chunk), "GLB chunk 0", "runs past the end")
    cases["tiny.glb"] = (good[:7], "GLB header", "needs 12")
    text = json.dumps(js).encode()
    broken = text[:-5] + b"     "
    cases["json.glb"] = (_raw_glb(broken, binary), "GLB JSON chunk", "malformed JSON")
    over = json.loads(json.dumps(js))
    over["accessors"][3]["count"] = 10_000
    cases["range.glb"] = (pack_glb(over, binary), "accessors[3].count", "out of range")
    no_bin = json.loads(json.dumps(js))
    cases["nobin.glb"] = (_raw_glb(json.dumps(no_bin).encode(), None), "buffers[0]",
                          "missing buffer")
    dangling = json.loads(json.dumps(js))
    dangling["skins"][0]["inverseBindMatrices"] = 99
    cases["index.glb"] = (pack_glb(dangling, binary), "skins[0].inverseBindMatrices",
                          "refers to accessors[99]")
    view = json.loads(json.dumps(js))
    view["bufferViews"][0]["byteOffset"] = len(binary)
    cases["view.glb"] = (pack_glb(view, binary), "bufferViews[0]", "outside buffers[0]")
    skinless = json.loads(json.dumps(js))
    del skinless["skins"]
    cases["skinless.glb"] = (pack_glb(skinless, binary), "skins", "no skin")
    times = json.loads(json.dumps(js))
    times["animations"][0]["samplers"][0]["interpolation"] = "BEZIER"
    cases["interp.glb"] = (pack_glb(times, binary), "animations[0].samplers[0].interpolation",
                           "LINEAR, STEP or CUBICSPLINE")
    version = json.loads(json.dumps(js))
    version["asset"]["version"] = "1.0"
    cases["version.glb"] = (pack_glb(version, binary), "asset.version", "glTF 2")
    for name, (data, where, words) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(GLTFError) as info:
            read_gltf(path)
        err = info.value
        assert isinstance(err, FileFormatError) and isinstance(err, MotionComposerError)
        assert err.where == where, (name, str(err))
        assert words in str(err), (name, str(err))
        assert str(path) in str(err) and err.path == str(path)


def _raw_glb(text: bytes, binary: bytes | None) -> bytes:
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    if binary is not None:
        body += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_gltf_json_with_external_bin_and_data_uri(tmp_path):
    js, binary = _valid(tmp_path)
    reference = read_gltf(tmp_path / "valid.glb")
    folder = tmp_path / "sub dir"
    folder.mkdir()
    (folder / "data 1.bin").write_bytes(binary)
    ext = json.loads(json.dumps(js))
    ext["buffers"][0]["uri"] = "data%201.bin"
    (folder / "external.gltf").write_text(json.dumps(ext))
    inline = json.loads(json.dumps(js))
    inline["buffers"][0]["uri"] = ("data:application/octet-stream;base64," +
                                   base64.b64encode(binary).decode())
    (folder / "inline.gltf").write_text(json.dumps(inline))
    for name in ("external.gltf", "inline.gltf"):
        c = read_gltf(folder / name)
        np.testing.assert_array_equal(c.skeleton.offsets, reference.skeleton.offsets)
        np.testing.assert_array_equal(c.motions[0].rotations, reference.motions[0].rotations)
        np.testing.assert_array_equal(c.meshes[0].positions, reference.meshes[0].positions)
    ext["buffers"][0]["uri"] = "gone.bin"
    (folder / "missing.gltf").write_text(json.dumps(ext))
    with pytest.raises(GLTFError) as info:
        read_gltf(folder / "missing.gltf")
    assert info.value.where == "buffers[0].uri" and "gone.bin" in str(info.value)
    (folder / "short.gltf").write_text(json.dumps(inline).replace('"byteLength": ',
                                                                  '"byteLength": 9'))
    with pytest.raises(GLTFError) as info:
        read_gltf(folder / "short.gltf")
    assert info.value.where == "buffers[0].byteLength"


# =========================================================================== writing
def _assert_same_character(a: Character, b: Character, motion_a, motion_b) -> None:
    size = _size(a)
    sa, sb = a.skeleton, b.skeleton
    assert sa.names == sb.names and sa.channels == sb.channels
    np.testing.assert_array_equal(sa.parents, sb.parents)
    np.testing.assert_allclose(sb.offsets, sa.offsets, atol=1e-6 * size, rtol=0)
    assert [s.name for s in sa.end_sites] == [s.name for s in sb.end_sites]
    np.testing.assert_allclose([s.offset for s in sb.end_sites],
                               [s.offset for s in sa.end_sites], atol=1e-6 * size, rtol=0)
    assert motion_b.num_frames == motion_a.num_frames
    assert motion_b.frame_time == pytest.approx(motion_a.frame_time, rel=1e-12)
    assert _same_rotations(motion_b.rotations, motion_a.rotations) < 1e-5
    np.testing.assert_allclose(motion_b.translations, motion_a.translations,
                               atol=1e-6 * size, rtol=0)
    assert _same_rotations(b.bind_rotations, a.bind_rotations) < 1e-5
    assert len(a.meshes) == len(b.meshes)
    for ma, mb in zip(a.meshes, b.meshes):
        np.testing.assert_allclose(mb.positions, ma.positions, atol=1e-6 * size, rtol=0)
        np.testing.assert_array_equal(mb.triangles, ma.triangles)
        k = ma.joints.shape[1]
        np.testing.assert_array_equal(mb.joints[:, :k][ma.weights > 0],
                                      ma.joints[ma.weights > 0])
        np.testing.assert_allclose(mb.weights[:, :k], ma.weights, atol=1e-7)


@pytest.mark.parametrize("name,animation,suffix", [(ROBOT, "Death", ".glb"),
                                                   (FOX, "Run", ".gltf"),
                                                   (TEST_CHARACTER, SWING, ".glb"),
                                                   (TEST_CHARACTER, SWING, ".gltf")])
def test_round_trip_write_read(tmp_path, name, animation, suffix):
    character = read_gltf(character_path(name))
    motion = character.motion(animation)
    out = tmp_path / f"out{suffix}"
    write_gltf(motion, character, out)
    again = read_gltf(out)
    assert [m.name for m in again.motions] == [animation]
    _assert_same_character(character, again, motion, again.motions[0])
    # the written file is plain glTF: the independent reader finds the same skinned mesh
    if suffix == ".glb":
        mini = _Mini(out)
        for mesh, ref in zip(character.meshes, mini.skinned_world_vertices()):
            np.testing.assert_allclose(ref, mesh.positions, atol=1e-5 * _size(character))


def test_write_is_atomic_and_checks_the_skeleton(tmp_path, robot, fox):
    out = tmp_path / "robot.glb"
    write_gltf(robot.motions[0], robot, out)
    before = out.read_bytes()
    with pytest.raises(MotionComposerError):
        write_gltf(fox.motions[0], robot, out)           # another character's skeleton
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["robot.glb"]


def test_skeleton_only_file_and_bvh_export(tmp_path, robot):
    """A motion without a character (joint axes along the world's), and BVH export of a glTF
    character: read back, FK agrees."""
    motion = robot.motion("Wave")
    write_gltf(motion, None, tmp_path / "bare.glb")
    bare = read_gltf(tmp_path / "bare.glb")
    assert bare.meshes == ()
    size = _size(robot)
    np.testing.assert_allclose(forward_kinematics(bare.motions[0]).positions,
                               forward_kinematics(motion).positions, atol=1e-5 * size)
    write_bvh(motion, tmp_path / "wave.bvh")
    back = read_bvh(tmp_path / "wave.bvh")
    assert back.skeleton.source.units == "m" and back.skeleton.source.up_axis == "+Y"
    assert back.skeleton.channels == motion.skeleton.channels
    np.testing.assert_allclose(forward_kinematics(back).all_positions(),
                               forward_kinematics(motion).all_positions(), atol=1e-5 * size)


@pytest.fixture(scope="module")
def retargeted(robot, tmp_path_factory):
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    target = robot.rest_motion()
    correspondence = automap(target.skeleton, performer.skeleton)
    motion = retarget(performer, target, correspondence)
    out = tmp_path_factory.mktemp("retarget") / "walk_on_robot.glb"
    write_gltf(motion, robot, out)
    return motion, out


def test_retarget_cmu_walk_onto_robot_exports(robot, retargeted):
    motion, out = retargeted
    assert motion.skeleton is robot.skeleton and motion.num_frames == 994
    again = read_gltf(out)
    assert again.fps == pytest.approx(motion.fps)         # the file records its rate
    assert again.motions[0].num_frames == motion.num_frames
    size = _size(robot)
    np.testing.assert_allclose(forward_kinematics(again.motions[0]).positions,
                               forward_kinematics(motion).positions, atol=1e-5 * size)
    travel = np.ptp(forward_kinematics(motion).positions[:, robot.skeleton.index["Hips"]],
                    axis=0)
    assert travel.max() > 2.0                               # it walks


# =========================================================================== the CLI
def _info(capsys, *args):
    from motion_composer.app.cli import main
    code = main(["info", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_info_reads_gltf(capsys, tmp_path):
    code, out, err = _info(capsys, shared_path(ROBOT))
    assert code == 0 and not err
    assert "joints:      43" in out and "skins:       4" in out
    assert "animations:  14: Dance (101 frames" in out and "meshes:      19 (15 rigid" in out
    code, out, _ = _info(capsys, shared_path(FOX), "--json")
    data = json.loads(out)
    assert data["frames"] == 104 and data["fps"] == 30.0 and data["joints"] == FOX_JOINTS
    assert [a["name"] for a in data["animations"]] == ["Survey", "Walk", "Run"]
    assert data["meshes"][0]["vertices"] == 1728 and data["units"] == "m"
    # a character without animation: its bind pose, one frame
    path, _ = chain_character(tmp_path, animate=False, name="still.glb")
    code, out, _ = _info(capsys, path, "--json")
    data = json.loads(out)
    assert code == 0 and data["frames"] == 1 and data["joints"] == ["hip", "spine", "head"]
    assert data["animations"] == [] and data["motion_shown"] == "bind pose (no animation)"
    # errors: one line, exit 2
    (tmp_path / "bad.glb").write_bytes(b"glTF\x02\x00\x00\x00")
    code, out, err = _info(capsys, tmp_path / "bad.glb")
    assert code == 2 and err.count("\n") == 1 and "GLB header" in err
    code, out, err = _info(capsys, path, "--units", "cm")
    assert code == 2 and "BVH files only" in err


# =========================================================================== Blender
BLENDER_GLTF_SCRIPT = textwrap.dedent(r'''
    import builtins, json, sys
    import bpy
    import numpy
    import io_anim_bvh.import_bvh as import_bvh

    # Blender 3.4's glTF importer uses numpy.bool, which numpy 1.24 removed
    if not hasattr(numpy, "bool"):
        numpy.bool = bool
    # and its BVH importer opens files with mode 'rU', which Python 3.11 refuses
    def _open(file, mode="r", *args, **kwargs):
        return builtins.open(file, mode.replace("U", ""), *args, **kwargs)
    import_bvh.open = _open

    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    scene = bpy.context.scene
    results = {}
    for item in job["files"]:
        before = set(bpy.data.objects)
        scene.render.fps = item["fps"]
        scene.render.fps_base = 1.0
        if item["kind"] == "gltf":
            bpy.ops.import_scene.gltf(filepath=item["path"])
            offset = 0                       # glTF time t lands on scene frame t * fps
        else:
            bpy.ops.import_anim.bvh(filepath=item["path"], target="ARMATURE",
                                    global_scale=1.0, rotate_mode="NATIVE", axis_forward="Y",
                                    axis_up="Z", frame_start=1, use_fps_scale=False,
                                    update_scene_fps=False, update_scene_duration=False)
            offset = 1                       # file frame f is scene frame f + 1
        new = [o for o in bpy.data.objects if o not in before]
        arm = [o for o in new if o.type == "ARMATURE"][0]
        action = arm.animation_data.action
        positions = {}
        for f in item["frames"]:
            scene.frame_set(f + offset)
            positions[f] = {pb.name: list(arm.matrix_world @ pb.head) for pb in arm.pose.bones}
        results[item["key"]] = {"action": action.name, "positions": positions}
        for o in new:
            bpy.data.objects.remove(o, do_unlink=True)
    json.dump(results, open(job["out"], "w"))
''')


@pytest.mark.blender
def test_blender_reads_what_we_read_and_write(tmp_path, robot, fox, retargeted):
    """Blender's glTF importer on (1) the original data files and (2) our GLB files, and its BVH
    importer on (3) our BVH of a glTF character: its pose-bone heads (which do not depend on
    bone orientation) equal our forward kinematics within 1e-4 of the character's height.
    Blender keys quaternions per component, so frames are compared on the files' key times
    (the originals are read at their 24 fps keys here)."""
    blender_or_skip()
    robot24 = read_gltf(shared_path(ROBOT), fps=24)
    fox24 = read_gltf(shared_path(FOX), fps=24)
    walk, walk_path = retargeted
    write_gltf(fox.motion("Walk"), fox, tmp_path / "fox_walk.glb")
    write_bvh(robot.motion("Dance"), tmp_path / "robot_dance.bvh")
    write_gltf(robot.motion("Jump"), robot, tmp_path / "robot_jump.glb")
    cases = [  # key, kind, path, fps, motion, frames, Y-up file (glTF) or not
        ("robot original", "gltf", shared_path(ROBOT), 24, robot24.motion("Dance"),
         [0, 17, 40, 80], True),
        ("fox original", "gltf", shared_path(FOX), 24, fox24.motion("Survey"), [0, 33, 82],
         True),
        ("robot jump", "gltf", tmp_path / "robot_jump.glb", 30, robot.motion("Jump"),
         [0, 11, 22], True),
        ("fox walk", "gltf", tmp_path / "fox_walk.glb", 30, fox.motion("Walk"), [0, 9, 22],
         True),
        ("walk on robot", "gltf", walk_path, 120, walk, [0, 333, 993], True),
        ("robot dance bvh", "bvh", tmp_path / "robot_dance.bvh", 30, robot.motion("Dance"),
         [0, 50, 100], False),
    ]
    job = {"files": [{"key": k, "kind": kind, "path": str(p), "fps": fps, "frames": frames}
                     for k, kind, p, fps, _, frames, _ in cases]}
    results = run_blender(BLENDER_GLTF_SCRIPT, "script.py", job, tmp_path)
    for key, kind, _, _, motion, frames, y_up in cases:
        ours = forward_kinematics(motion).positions
        sk = motion.skeleton
        height = float(np.ptp(ours[0, :, 1]))
        got = results[key]
        if key.endswith("original"):
            assert motion.name in got["action"]
        for f in frames:
            bones = got["positions"][str(f)]
            assert set(sk.names) <= set(bones), key
            theirs = np.array([bones[n] for n in sk.names])
            if y_up:                          # Blender's Z-up: (x, y, z) -> (x, -z, y)
                theirs = np.stack([theirs[:, 0], theirs[:, 2], -theirs[:, 1]], axis=1)
            err = np.abs(theirs - ours[f]).max()
            assert err < 1e-4 * height, (key, f, err, height)


def test_the_retarget_command_takes_a_gltf_character_and_writes_glb(tmp_path, capsys):
    from motion_composer.app.cli import main
    from motion_composer.engine.formats.gltf import read_gltf
    robot = shared_path("target_robot_expressive.glb")
    out = tmp_path / "walk_on_robot.glb"
    code = main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(robot),
                 "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    back = read_gltf(out)
    assert back.skeleton.names == read_gltf(robot).skeleton.names
    assert back.meshes and sum(m.num_vertices for m in back.meshes) > 1000
    walk = back.motions[0]
    assert walk.num_frames > 200                    # resampled from 994 frames at 120 fps
    bvh = tmp_path / "walk_on_robot.bvh"
    assert main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(robot),
                 "-o", str(bvh)]) == 0
    from motion_composer.engine import read_bvh
    assert read_bvh(bvh).num_frames == 994


# =========================================================================== required extensions
ELY = "target_mixamo_ely.glb"


def _ely_requiring(tmp_path, name: str, required: list[str], meshopt: bool = False) -> Path:
    """Ely (shared data) rewritten to require ``required``; ``meshopt``: laid out as gltfpack
    and glTF-Transform write EXT_meshopt_compression (every buffer view reads a placeholder
    buffer without bytes; the extension points at the real, here uncompressed, data)."""
    js, binary = unpack_glb(shared_path(ELY).read_bytes())
    js["extensionsUsed"] = list(dict.fromkeys(js.get("extensionsUsed", []) +
                                              [e for e in required if isinstance(e, str)]))
    js["extensionsRequired"] = required
    if meshopt:
        js["buffers"].append({"byteLength": js["buffers"][0]["byteLength"],
                              "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
        for view in js["bufferViews"]:
            view["extensions"] = {"EXT_meshopt_compression": {
                "buffer": 0, "byteOffset": view.get("byteOffset", 0),
                "byteLength": view["byteLength"], "byteStride": 4,
                "count": view["byteLength"] // 4, "mode": "ATTRIBUTES"}}
            view["buffer"] = 1
    path = tmp_path / name
    path.write_bytes(pack_glb(js, binary))
    return path


def test_meshopt_compressed_file_is_refused_naming_the_extension(tmp_path, capsys):
    """A file that requires EXT_meshopt_compression (gltfpack -cc, gltf-transform meshopt or
    optimize) was read as if the extension were absent: its buffer views point at a
    placeholder buffer, and the error named a missing buffer. It names the extension now,
    from the reader and from the command line (one line, exit 2)."""
    path = _ely_requiring(tmp_path, "ely_meshopt.glb",
                          ["EXT_meshopt_compression", "KHR_mesh_quantization"], meshopt=True)
    with pytest.raises(GLTFError) as info:
        read_gltf(path)
    err = info.value
    assert err.where == "extensionsRequired" and err.path == str(path)
    assert "EXT_meshopt_compression" in str(err) and "KHR_mesh_quantization" not in str(err)
    from motion_composer.app.cli import main
    code = main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(path),
                 "-o", str(tmp_path / "out.bvh")])
    out, errtext = capsys.readouterr()
    assert code == 2 and not (tmp_path / "out.bvh").exists()
    assert len(errtext.strip().splitlines()) == 1
    assert "EXT_meshopt_compression" in errtext and str(path) in errtext


def test_required_extensions_the_reader_handles_or_ignores(tmp_path):
    """A required extension for appearance only (materials) or for quantized attributes
    (read as integer accessors) does not stop the reading: the same character as without;
    an unknown required extension is refused by name."""
    plain = read_gltf(shared_path(ELY))
    path = _ely_requiring(tmp_path, "ely_required.glb",
                          ["KHR_materials_specular", "KHR_texture_transform",
                           "KHR_mesh_quantization"])
    again = read_gltf(path)
    assert again.skeleton.names == plain.skeleton.names
    assert np.array_equal(again.bind_positions, plain.bind_positions)
    assert again.num_vertices == plain.num_vertices > 0
    odd = _ely_requiring(tmp_path, "ely_instanced.glb", ["EXT_mesh_gpu_instancing"])
    with pytest.raises(GLTFError, match="EXT_mesh_gpu_instancing") as info:
        read_gltf(odd)
    assert info.value.where == "extensionsRequired"
    bad = _ely_requiring(tmp_path, "ely_bad_list.glb", [3])
    with pytest.raises(GLTFError, match="list of extension names"):
        read_gltf(bad)


# =========================================================================== which way is up
@pytest.mark.parametrize("name", [
    "target_mixamo_ely.glb", "target_mixamo_mannequin.glb", ROBOT, FOX, "fbx/mixamo.fbx",
    "fbx/maya_kenney_character_7700_binary.fbx", "fbx/maya_character_7500_binary.fbx",
    "fbx/maya_character_6100_ascii.fbx", "fbx/Samba_Dancing.fbx"])
def test_every_shared_character_stands_up_without_a_doubt(name):
    """glTF is +Y up by definition and FBX says its axes: every character of ../shared/data
    stands up as read (the fox too, a quadruped read as a humanoid whose head is 59 degrees
    forward of its legs: the legs, hips over their ends, tell which way it stands)."""
    from motion_composer.engine.formats import read_character
    assert read_character(shared_path(name)).skeleton.source.doubt == ""


def z_up_ely(folder: Path) -> Path:
    """``folder/ely_z_up.glb``: Ely written +Z up (its armature node turned a further 90
    degrees about x), as Blender's exporter writes it with "+Y Up" unticked."""
    js, binary = unpack_glb(shared_path("target_mixamo_ely.glb").read_bytes())
    for i in js["scenes"][js.get("scene", 0)]["nodes"]:
        node = js["nodes"][i]
        assert "matrix" not in node
        turned = Rotation.from_euler("x", 90, degrees=True) * Rotation.from_quat(
            node.get("rotation", [0, 0, 0, 1]))
        node["rotation"] = turned.as_quat().tolist()
    path = folder / "ely_z_up.glb"
    path.write_bytes(pack_glb(js, binary))
    return path


def test_a_gltf_written_z_up_is_said_to_lie_in_one_line(tmp_path, capsys):
    """A glTF written with +Z up (against the format's definition, as Blender's exporter does
    with "+Y Up" unticked): Ely's armature turned a further 90 degrees about x. It is read as
    the file says (lying), and ``info``, ``retarget`` and the reader's source say so in one
    line that names the file, the axis it stands along and the flag that reads it up."""
    from motion_composer.app.cli import main
    from motion_composer.engine.formats import read_character
    lying = z_up_ely(tmp_path)
    source = read_character(lying).skeleton.source
    assert source.doubt.startswith("the figure stands along +Z, not +Y, in its bind pose")
    assert source.overrides == (("up_axis", "+Z"),)
    said = f"motion-composer: warning: {lying}: {source.doubt}; if that is wrong, give "
    code, _, err = _info(capsys, lying)
    assert code == 0 and err == said + "--up-axis +Z\n"
    code = main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(lying),
                 "-o", str(tmp_path / "out.bvh"), "--frames", "0:20"])
    err = capsys.readouterr().err
    assert code == 0 and err == said + "--target-up-axis +Z\n"


def test_a_bind_pose_that_lies_under_clips_that_stand_raises_no_doubt(tmp_path, capsys):
    """A BANDAI clip written as glTF (here by our writer; Blender's exporter does the same)
    keeps the BVH's zero pose as its bind pose, and that lies along +X while every frame of
    the walk stands along +Y. ``info`` said to read it with ``--up-axis +X``, which would lay
    the walking figure down: the clips tell, and the file is read without a doubt. The
    same skeleton without clips still says it lies."""
    from motion_composer.engine.formats import read_character, read_performer
    from motion_composer.engine.formats.figure import lying_doubt
    walk = read_performer(shared_path("bandai1_walk_normal_001.bvh"))
    assert lying_doubt(walk.skeleton, "zero pose")[1] == "+X"
    path = tmp_path / "bandai_walk.glb"
    write_gltf(walk, None, path)
    character = read_character(path)
    assert character.skeleton.source.doubt == "" and character.skeleton.source.overrides == ()
    assert all(m.skeleton is character.skeleton for m in character.motions)
    code, out, err = _info(capsys, path)
    assert code == 0 and err == "" and "up axis:     +Y" in out
    doubt, axis = lying_doubt(character.skeleton, "bind pose")
    assert axis == "+X" and doubt.startswith("the figure stands along +X, not +Y, in its bind")


def test_shin_end_nodes_above_the_knees_raise_no_doubt_where_the_shins_stand(tmp_path):
    """The robot's legs end at its shins (its feet are control joints under the root), so its
    stance was measured from the hips to the shins' ``_end`` nodes. Blender's glTF of the
    robot puts those nodes above the knees, and the standing robot was said to stand along
    -Y (160 degrees off). An End Site that turns back up the leg is no ankle: the leg ends
    at the shin, that file reads without a doubt, and the robot turned Z-up (End Sites and
    all) still lies along +Z."""
    from motion_composer.engine.formats import read_character
    js, binary = unpack_glb(shared_path(ROBOT).read_bytes())
    ends = [n for n in js["nodes"] if n.get("name") in ("LowerLegL_end", "LowerLegR_end")]
    assert len(ends) == 2
    for node in ends:
        node["translation"] = [0.0, -10 * node["translation"][1], 0.0]
    raised = tmp_path / "robot_raised_ends.glb"
    raised.write_bytes(pack_glb(js, binary))
    character = read_character(raised)
    sk = character.skeleton
    sites = {s.name: s for s in sk.end_sites}
    for side in "LR":
        shin = sk.index[f"LowerLeg{side}"]
        end = character.bind_positions[shin] + sites[f"LowerLeg{side}_end"].offset
        assert end[1] > character.bind_positions[shin][1] > 0.0     # above the knee
    assert sk.source.doubt == ""
    for i in js["scenes"][js.get("scene", 0)]["nodes"]:
        node = js["nodes"][i]
        node["rotation"] = (Rotation.from_euler("x", 90, degrees=True) * Rotation.from_quat(
            node.get("rotation", [0, 0, 0, 1]))).as_quat().tolist()
    lying = tmp_path / "robot_z_up.glb"
    lying.write_bytes(pack_glb(js, binary))
    source = read_character(lying).skeleton.source
    assert source.doubt.startswith("the figure stands along +Z, not +Y")
    assert source.overrides == (("up_axis", "+Z"),)


def test_a_gltf_written_z_up_read_with_its_up_axis_is_the_file_written_y_up(tmp_path, capsys):
    """The same file read with the up axis the warning names (``up_axis="+Z"``,
    ``--target-up-axis +Z``, a project's target ``up_axis``) is Ely as written +Y up: every
    joint, bind axis and vertex within 1e-9; no doubt; and what is written on it stands up.
    Read with a wrong axis it still lies, and the doubt names the right one."""
    from motion_composer.app.cli import main
    from motion_composer.engine.formats import read_character, read_motion
    lying = z_up_ely(tmp_path)
    ely = read_character(shared_path("target_mixamo_ely.glb"))
    stood = read_character(lying, up_axis="+Z")
    assert stood.skeleton.source.doubt == "" and stood.skeleton.source.up_axis == "+Z"
    np.testing.assert_allclose(stood.bind_positions, ely.bind_positions, atol=1e-9)
    np.testing.assert_allclose(stood.skeleton.offsets, ely.skeleton.offsets, atol=1e-9)
    np.testing.assert_allclose(stood.bind_rotations, ely.bind_rotations, atol=1e-9)
    assert len(stood.meshes) == len(ely.meshes) > 0
    for a, b in zip(stood.meshes, ely.meshes):
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-9)
    np.testing.assert_allclose(read_motion(lying, up_axis="+Z").translations,
                               ely.rest_motion().translations, atol=1e-9)
    wrong = read_character(lying, up_axis="-Z").skeleton.source
    assert "stands along -Y" in wrong.doubt and wrong.overrides == (("up_axis", "+Z"),)
    code, out, err = _info(capsys, lying, "--up-axis", "+Z")
    assert code == 0 and err == "" and "up axis:     +Z (given)" in out
    written = tmp_path / "walk_on_ely.glb"
    code = main(["retarget", str(clip_path("cmu_131_01_walk.bvh")), "--target", str(lying),
                 "--target-up-axis", "+Z", "-o", str(written), "--frames", "0:20"])
    assert code == 0 and capsys.readouterr().err == ""
    assert read_character(written).skeleton.source.doubt == ""


_BLENDER_Z_UP = '''
import json, sys
import bpy, numpy
if not hasattr(numpy, "bool"):
    numpy.bool = bool   # Blender 3.4's glTF importer names numpy.bool (gone in 1.24 to 1.26)
job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=job["source"])
for name, yup in (("z_up.glb", False), ("y_up.glb", True)):
    bpy.ops.export_scene.gltf(filepath=job["folder"] + "/" + name, export_format="GLB",
                              export_yup=yup)
json.dump({"ok": True}, open(job["out"], "w"))
'''


@pytest.mark.blender
def test_blenders_gltf_written_z_up_read_with_its_up_axis_is_its_y_up_export(tmp_path):
    """Blender's own glTF exporter with "+Y Up" unticked (a Z-up file, as artists write by
    mistake) and ticked, both of Ely: the Z-up file's doubt names +Z, and read with it every
    joint of the bind pose and of the animation and every vertex is the Y-up file's within
    a micrometre (float32 data)."""
    from motion_composer.engine.formats import read_character
    run_blender(_BLENDER_Z_UP, "z_up.py", {"source": str(shared_path(
        "target_mixamo_ely.glb")), "folder": str(tmp_path)}, tmp_path)
    source = read_character(tmp_path / "z_up.glb").skeleton.source
    assert "stands along +Z" in source.doubt and source.overrides == (("up_axis", "+Z"),)
    stood = read_character(tmp_path / "z_up.glb", up_axis="+Z")
    written_up = read_character(tmp_path / "y_up.glb")
    assert stood.skeleton.source.doubt == "" and stood.skeleton.names == written_up.skeleton.names
    np.testing.assert_allclose(stood.bind_positions, written_up.bind_positions, atol=1e-6)
    assert len(stood.motions) == len(written_up.motions) > 0
    for a, b in zip(stood.motions, written_up.motions):
        np.testing.assert_allclose(forward_kinematics(a).positions,
                                   forward_kinematics(b).positions, atol=1e-6)
    for a, b in zip(stood.meshes, written_up.meshes):
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-6)


@pytest.mark.parametrize("break_it", [
    lambda js: js["nodes"][0].setdefault("children", []).append([1]),
    lambda js: js["nodes"][1].setdefault("children", []).append(0),
    lambda js: js["nodes"].append(3)], ids=["a child that is no index", "two parents",
                                             "a node that is no object"])
def test_a_malformed_node_tree_read_with_an_up_axis_is_refused_as_without(tmp_path, break_it):
    """The up axis turns the scene under a node of its own, added once the node tree as
    written is checked: a malformed tree gets the same one-line error, naming the same node,
    as without the option."""
    js, binary = unpack_glb(shared_path("target_mixamo_ely.glb").read_bytes())
    break_it(js)
    path = tmp_path / "broken.glb"
    path.write_bytes(pack_glb(js, binary))
    with pytest.raises(GLTFError) as plain:
        read_gltf(path)
    with pytest.raises(GLTFError) as turned:
        read_gltf(path, up_axis="+Z")
    assert str(turned.value) == str(plain.value) and "nodes[" in str(plain.value)
