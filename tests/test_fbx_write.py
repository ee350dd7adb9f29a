"""Writing FBX (:mod:`engine.formats.fbx.write`): the document our writer produces, read back
with :func:`parse_binary`; then Blender 3.4's importer as the independent reader (joint world
positions on every frame, vertex groups, skinned vertices) and Blender's exporter as the
reference for the structure the FBX SDK writes."""
from __future__ import annotations

import collections

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from blender_util import run_blender_fbx
from conftest import REPO, clip_path, shared_path
from motion_composer.engine.errors import ExportError
from motion_composer.engine.formats import read_character, read_motion
from motion_composer.engine.formats.fbx.binary import parse_binary
from motion_composer.engine.formats.fbx.encode import CREATION_TIME, FILE_ID
from motion_composer.engine.formats.fbx.nodes import FBX_TICKS_PER_SECOND
from motion_composer.engine.formats.fbx.write import (TIME_MODE_CUSTOM, fbx_document,
                                                      format_fbx, frame_rate, rotation_order,
                                                      write_fbx)
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.quaternions import qconj, qmul
from motion_composer.engine.skinning import skin_character

SECTIONS = ["FBXHeaderExtension", "FileId", "CreationTime", "Creator", "GlobalSettings",
            "Documents", "References", "Definitions", "Objects", "Connections", "Takes"]
TEST_CHARACTER = REPO / "resources" / "characters" / "test_character.glb"
#: a rate FBX does not name (written as CustomFrameRate)
CUSTOM_FPS = 37.5
#: frames whose skinned vertices are compared with Blender's
SKIN_AT = [0, 20]
#: frames of the bundled walk written (2 s at 120 fps; Blender checks every one)
WALK_FRAMES = 240


# --------------------------------------------------------------------------- helpers
def objects_by_id(tree):
    return {o.props[0]: o for o in tree.find("Objects").children}


def props70(node) -> dict:
    block = node.find("Properties70")
    return {p.props[0]: p.props[4:] for p in block.children} if block is not None else {}


def class_of(obj) -> str:
    return obj.props[2]


def name_of(obj) -> str:
    return obj.props[1].split("\x00\x01")[0]


def connections(tree):
    return [tuple(c.props) for c in tree.find("Connections").children]


def models(tree) -> dict:
    """Joint name -> its LimbNode Model."""
    return {name_of(o): o for o in tree.find("Objects").find_all("Model")
            if class_of(o) == "LimbNode"}


def curve_values(tree, model_id, prop) -> np.ndarray:
    """``(F, 3)`` the X, Y, Z curves animating ``prop`` of object ``model_id``."""
    objs = objects_by_id(tree)
    links = connections(tree)
    node = [c for kind, c, p, *rest in links if kind == "OP" and p == model_id and
            rest == [prop]]
    assert len(node) == 1
    curves = {rest[0]: objs[c] for kind, c, p, *rest in links if kind == "OP" and
              p == node[0]}
    return np.stack([curves[f"d|{a}"].find("KeyValueFloat").props[0] for a in "XYZ"], axis=1)


def key_times(tree) -> np.ndarray:
    curve = tree.find("Objects").find("AnimationCurve")
    return curve.find("KeyTime").props[0]


def fbx_rotation(euler_xyz: np.ndarray, order: int) -> Rotation:
    """The rotation FBX means by ``Lcl Rotation`` angles (X, Y, Z degrees) in ``RotationOrder``
    ``order`` (eEulerXYZ = 0: X applied first, i.e. extrinsic x, y, z)."""
    seq = ("XYZ", "XZY", "YZX", "YXZ", "ZXY", "ZYX")[order]
    angles = np.stack([euler_xyz[..., "XYZ".index(a)] for a in seq], axis=-1)
    return Rotation.from_euler(seq.lower(), angles, degrees=True)


@pytest.fixture(scope="module")
def walk():
    return read_motion(clip_path("cmu_131_01_walk.bvh")).frames(slice(0, WALK_FRAMES))


@pytest.fixture(scope="module")
def jump():
    """The rotation orders YXZ and XYZ, at 119.875 fps: NTSC 119.88 fps written (within 1e-4),
    which Blender puts between its whole frames."""
    return read_motion(clip_path("fair1_child8_jumping.bvh")).frames(slice(0, WALK_FRAMES))


@pytest.fixture(scope="module")
def fox():
    return read_character(shared_path("target_fox.glb"))


@pytest.fixture(scope="module")
def robot():
    """19 meshes, 15 of them rigid parts bound to one joint; a bind pose folded from a 100x
    scaled node (see engine.formats.gltf)."""
    return read_character(shared_path("target_robot_expressive.glb"))


@pytest.fixture(scope="module")
def test_character():
    return read_character(TEST_CHARACTER)


# --------------------------------------------------------------------------- the document
def test_sections_and_header(walk):
    tree = parse_binary(format_fbx(walk))
    assert tree.props == [np.int32(7400)]
    assert [c.name for c in tree.children] == SECTIONS
    assert tree.find("FileId").props == [FILE_ID]
    assert tree.find("CreationTime").props == [CREATION_TIME]
    header = tree.find("FBXHeaderExtension")
    assert header.find("FBXVersion").props == [np.int32(7400)]
    settings = props70(tree.find("GlobalSettings"))
    assert {k: int(settings[k][0]) for k in ("UpAxis", "UpAxisSign", "FrontAxis",
                                              "FrontAxisSign", "CoordAxis", "CoordAxisSign")} \
        == {"UpAxis": 1, "UpAxisSign": 1, "FrontAxis": 2, "FrontAxisSign": 1, "CoordAxis": 0,
            "CoordAxisSign": 1}
    assert settings["UnitScaleFactor"] == [1.0]                      # centimetres
    assert int(settings["TimeMode"][0]) == 1                         # 120 fps
    take = tree.find("Takes").find("Take")
    assert take.props == [walk.name]
    assert props70(tree.find("Documents").find("Document"))["ActiveAnimStackName"] == \
        [walk.name]


def test_definitions_count_the_objects(fox):
    tree = parse_binary(format_fbx(fox.motions[0], fox))
    counted = collections.Counter(o.name for o in tree.find("Objects").children)
    definitions = tree.find("Definitions")
    declared = {t.props[0]: int(t.find("Count").props[0])
                for t in definitions.find_all("ObjectType")}
    assert declared.pop("GlobalSettings") == 1
    assert declared == dict(counted)
    assert int(definitions.find("Count").props[0]) == sum(counted.values()) + 1
    J = fox.skeleton.num_joints
    assert counted["AnimationCurveNode"] == 2 * J and counted["AnimationCurve"] == 6 * J
    assert counted["AnimationStack"] == counted["AnimationLayer"] == 1
    templates = {t.props[0]: t.find("PropertyTemplate").props[0]
                 for t in definitions.find_all("ObjectType") if t.find("PropertyTemplate")}
    assert templates["Model"] == "FbxNode" and templates["Geometry"] == "FbxMesh"


def test_every_connection_joins_written_objects(fox):
    tree = parse_binary(format_fbx(fox.motions[0], fox))
    objs = objects_by_id(tree)
    assert len(objs) == len(tree.find("Objects").children)        # ids are unique
    for kind, child, parent, *prop in connections(tree):
        assert child in objs and (parent == 0 or parent in objs)
    parents = {c: p for kind, c, p, *_ in connections(tree) if kind == "OO" and
               objs[c].name == "Model" and (p == 0 or objs[p].name == "Model")}
    by_name = models(tree)
    sk = fox.skeleton
    for j, name in enumerate(sk.names):
        expected = 0 if j == 0 else by_name[sk.names[sk.parents[j]]].props[0]
        assert parents[by_name[name].props[0]] == expected


def test_keys_one_per_frame_at_the_rate(walk):
    tree = parse_binary(format_fbx(walk))
    times = key_times(tree)
    assert times.dtype == np.int64 and len(times) == walk.num_frames
    np.testing.assert_array_equal(times, np.rint(np.arange(walk.num_frames) *
                                                 FBX_TICKS_PER_SECOND / 120.0))


def test_curves_give_back_the_motion(fox):
    """The written T and R curves, read with FBX's Euler convention, are the motion's local
    transforms in each joint's own axes (the character's bind orientations), in cm."""
    motion = fox.motions[0]
    tree = parse_binary(format_fbx(motion, fox))
    sk = motion.skeleton
    bind_q = fox.bind_rotations
    parent_q = np.tile([0.0, 0.0, 0.0, 1.0], (sk.num_joints, 1))
    parent_q[1:] = bind_q[sk.parents[1:]]
    local = qmul(qconj(parent_q)[None], qmul(motion.rotations, bind_q[None]))
    translations = motion.local_translations()
    for j, name in enumerate(sk.names):
        model = models(tree)[name]
        order = int(props70(model).get("RotationOrder", [0])[0])
        assert order == rotation_order(sk.rotation_orders[j])[1]
        assert int(props70(model)["RotationActive"][0]) == 1
        rot = fbx_rotation(curve_values(tree, model.props[0], "Lcl Rotation"), order)
        err = (rot * Rotation.from_quat(local[:, j]).inv()).magnitude()
        assert err.max() < 1e-5, name
        t = Rotation.from_quat(np.broadcast_to(parent_q[j], (motion.num_frames, 4))).inv() \
            .apply(translations[:, j]) * 100.0
        np.testing.assert_allclose(curve_values(tree, model.props[0], "Lcl Translation"), t,
                                   atol=1e-3, err_msg=name)


def test_bind_pose_is_the_characters(fox):
    tree = parse_binary(format_fbx(fox.motions[0], fox))
    pose = tree.find("Objects").find("Pose")
    objs = objects_by_id(tree)
    nodes = list(pose.find_all("PoseNode"))
    assert int(pose.find("NbPoseNodes").props[0]) == len(nodes) == fox.skeleton.num_joints + 1
    bind = dict(zip(fox.skeleton.names, fox.bind_positions))
    for node in nodes:
        obj = objs[node.find("Node").props[0]]
        m = node.find("Matrix").props[0].reshape(4, 4).T                # column-major
        if class_of(obj) == "LimbNode":
            np.testing.assert_allclose(m[:3, 3], bind[name_of(obj)] * 100.0, atol=1e-9)
            rot = Rotation.from_matrix(m[:3, :3])
            j = fox.skeleton.index[name_of(obj)]
            assert (rot * Rotation.from_quat(fox.bind_rotations[j]).inv()).magnitude() < 1e-9
        else:
            np.testing.assert_array_equal(m, np.eye(4))


def test_skin_holds_the_meshes_weights(test_character):
    c = test_character
    tree = parse_binary(format_fbx(c.motions[0], c))
    objs = objects_by_id(tree)
    (geometry,) = tree.find("Objects").find_all("Geometry")
    mesh = c.meshes[0]
    np.testing.assert_allclose(geometry.find("Vertices").props[0].reshape(-1, 3),
                               mesh.positions * 100.0)
    polygons = geometry.find("PolygonVertexIndex").props[0].reshape(-1, 3)
    assert np.all(polygons[:, 2] < 0)
    polygons[:, 2] = -polygons[:, 2] - 1
    np.testing.assert_array_equal(polygons, mesh.triangles)
    normals = geometry.find("LayerElementNormal")
    np.testing.assert_allclose(normals.find("Normals").props[0].reshape(-1, 3), mesh.normals)
    total = np.zeros(mesh.num_vertices)
    dense = np.zeros((mesh.num_vertices, c.skeleton.num_joints))
    for v in range(mesh.num_vertices):
        np.add.at(dense[v], mesh.joints[v], mesh.weights[v])
    links = connections(tree)
    for cluster in (o for o in objs.values() if class_of(o) == "Cluster"):
        (joint,) = [objs[ch] for kind, ch, p, *_ in links if p == cluster.props[0]]
        j = c.skeleton.index[name_of(joint)]
        assert name_of(cluster) == name_of(joint)
        idx = cluster.find("Indexes").props[0]
        w = cluster.find("Weights").props[0]
        np.testing.assert_allclose(w, dense[idx, j])
        total[idx] += w
        link = cluster.find("TransformLink").props[0].reshape(4, 4).T
        transform = cluster.find("Transform").props[0].reshape(4, 4).T
        np.testing.assert_allclose(link @ transform, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(link[:3, 3], c.bind_positions[j] * 100.0, atol=1e-9)
    np.testing.assert_allclose(total, 1.0, atol=1e-6)


def test_rates_fbx_names_and_custom_ones():
    assert frame_rate(1 / 0.0083333) == (120.0, 1)
    assert frame_rate(30.0) == (30.0, 6)
    assert frame_rate(30000 / 1001) == (30000 / 1001, 9)
    assert frame_rate(37.5) == (37.5, TIME_MODE_CUSTOM)


def test_custom_rate_is_written(walk):
    motion = walk.resampled(CUSTOM_FPS)
    tree = parse_binary(format_fbx(motion))
    settings = props70(tree.find("GlobalSettings"))
    assert int(settings["TimeMode"][0]) == TIME_MODE_CUSTOM
    assert settings["CustomFrameRate"] == [37.5]
    np.testing.assert_array_equal(key_times(tree)[:3],
                                  np.rint(np.arange(3) * FBX_TICKS_PER_SECOND / 37.5))


def test_same_motion_same_bytes(walk):
    assert format_fbx(walk) == format_fbx(walk)


def test_motion_off_the_characters_skeleton_refused_and_file_kept(walk, fox, tmp_path):
    out = tmp_path / "out.fbx"
    out.write_bytes(b"previous")
    with pytest.raises(ExportError, match="retarget the motion onto the character"):
        write_fbx(walk, out, character=fox)
    assert out.read_bytes() == b"previous"
    with pytest.raises(ExportError, match="no frames"):
        fbx_document(walk.frames(slice(0, 0)))


def test_write_is_atomic_and_reads_back(walk, tmp_path):
    out = tmp_path / "walk.fbx"
    write_fbx(walk, out)
    assert out.read_bytes() == format_fbx(walk)
    assert [p.name for p in tmp_path.iterdir()] == ["walk.fbx"]


# --------------------------------------------------------------------------- Blender
@pytest.fixture(scope="module")
def blender(walk, jump, fox, robot, test_character, tmp_path_factory):
    """One Blender run: our walk and jump (skeletons only) and our fox (skinned, its own joint
    axes) imported and read on every frame; Blender's exporter writing the same walk and test
    character."""
    folder = tmp_path_factory.mktemp("fbx_blender")
    fox_motion = fox.motions[0]
    ours = {"walk": folder / "walk.fbx", "jump": folder / "jump.fbx", "fox": folder / "fox.fbx",
            "character": folder / "character.fbx", "custom": folder / "custom.fbx",
            "robot": folder / "robot.fbx"}
    write_fbx(robot.motions[0], ours["robot"], character=robot)
    write_fbx(walk, ours["walk"])
    write_fbx(walk.resampled(CUSTOM_FPS), ours["custom"])
    write_fbx(jump, ours["jump"])
    write_fbx(fox_motion, ours["fox"], character=fox)
    write_fbx(test_character.motions[0], ours["character"], character=test_character)
    job = {"exports": [{"key": "walk", "source": str(clip_path("cmu_131_01_walk.bvh")),
                        "out": str(folder / "walk_blender.fbx")},
                       {"key": "character",
                        "source": str(TEST_CHARACTER),
                        "out": str(folder / "character_blender.fbx")}],
           "imports": [{"key": "walk", "path": str(ours["walk"]), "frames": scene_frames(walk)},
                       {"key": "jump", "path": str(ours["jump"]), "frames": scene_frames(jump)},
                       {"key": "custom", "path": str(ours["custom"]),
                        "frames": scene_frames(walk.resampled(CUSTOM_FPS))},
                       {"key": "fox", "path": str(ours["fox"]),
                        "frames": scene_frames(fox_motion), "skin_at": SKIN_AT},
                       {"key": "robot", "path": str(ours["robot"]),
                        "frames": scene_frames(robot.motions[0]), "skin_at": SKIN_AT}]}
    result = run_blender_fbx(job, folder)
    result["ours"] = ours
    return result


def scene_frames(motion) -> list[float]:
    """Where Blender puts each key: frame = t * round(fps) + 1 (fractional at 119.875 fps)."""
    rate, _ = frame_rate(motion.fps)
    return list(np.arange(motion.num_frames) / rate * round(rate) + 1.0)


def blender_to_engine(p) -> np.ndarray:
    """Blender's world (+Z up; the importer turned our +Y up into it) to the engine's."""
    p = np.asarray(p, dtype=float)
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


def stature(motion) -> float:
    rest = forward_kinematics(motion.frames(slice(0, 1)), end_sites=False).positions[0]
    return float(np.ptp(rest, axis=0).max())


@pytest.mark.blender
@pytest.mark.parametrize("key", ["walk", "jump", "custom", "fox", "robot"])
def test_blender_gets_the_joint_positions_on_every_frame(key, blender, walk, jump, fox, robot):
    motion = {"walk": walk, "jump": jump, "custom": walk.resampled(CUSTOM_FPS),
              "fox": fox.motions[0], "robot": robot.motions[0]}[key]
    result = blender["imports"][key]
    assert result["armatures"] == 1
    # Blender keeps the rate as a whole number and a float32 divisor
    assert result["fps"] == pytest.approx(frame_rate(motion.fps)[0], rel=1e-6)
    ours = forward_kinematics(motion, end_sites=False).positions
    names = motion.skeleton.names
    theirs = np.array([[frame[n] for n in names] for frame in result["positions"]])
    err = np.linalg.norm(blender_to_engine(theirs) - ours, axis=-1)
    assert err.max() <= 1e-4 * stature(motion), f"{key}: {err.max():.3g} m"


@pytest.mark.blender
@pytest.mark.parametrize("key", ["fox", "robot"])
def test_blender_skins_the_meshes_as_we_do(key, blender, fox, robot):
    """Every mesh: one vertex group per joint that weighs on it, holding the vertices it
    weighs, and Blender's skinned vertices ours at two frames (the robot's 19 meshes are
    mostly rigid parts bound to one joint)."""
    character = fox if key == "fox" else robot
    motion = character.motions[0]
    meshes = blender["imports"][key]["meshes"]
    assert sorted(meshes) == sorted(m.name for m in character.meshes)
    ours = skin_character(character, motion, frames=SKIN_AT)
    for m, skinned in zip(character.meshes, ours):
        mesh = meshes[m.name]
        assert mesh["vertices"] == m.num_vertices
        weighed = (m.weights > 0)
        groups = {character.skeleton.names[j]: int(np.any((m.joints == j) & weighed,
                                                          axis=1).sum())
                  for j in np.unique(m.joints[weighed])}
        assert mesh["group_sizes"] == groups, m.name
        for k, frame in enumerate(SKIN_AT):
            theirs = blender_to_engine(mesh["skinned"][str(frame)])
            err = np.linalg.norm(theirs - skinned[k], axis=-1).max()
            assert err <= 1e-4 * stature(motion), f"{m.name} frame {frame}: {err:.3g}"


def structure(path):
    """Top-level sections, Definitions (type -> count, template), objects per (type, class)
    with their record names and P names."""
    tree = parse_binary(path.read_bytes())
    definitions = {}
    for t in tree.find("Definitions").find_all("ObjectType"):
        template = t.find("PropertyTemplate")
        definitions[t.props[0]] = (
            int(t.find("Count").props[0]),
            template.props[0] if template else None,
            set(props70(template)) if template else set())
    objects = collections.defaultdict(lambda: (set(), set()))
    for o in tree.find("Objects").children:
        records, ps = objects[(o.name, class_of(o))]
        records.update(c.name for c in o.children)
        ps.update(props70(o))
    counted = collections.Counter(o.name for o in tree.find("Objects").children)
    return [c.name for c in tree.children], definitions, dict(objects), counted


#: objects Blender's exporter writes and ours does not: its armature object and the glTF
#: character's leaf nodes (Null models, with their attributes)
BLENDER_ONLY = {("Model", "Null"), ("NodeAttribute", "Null")}
#: properties Blender writes because its values differ from the template, and ours do not:
#: Lcl Scaling everywhere (ours never scales), the mesh's Lcl Rotation (its axis conversion)
BLENDER_ONLY_PROPS = {"Lcl Scaling"}
BLENDER_ONLY_MESH_PROPS = {"Lcl Rotation"}


@pytest.mark.blender
@pytest.mark.parametrize("key", ["walk", "character"])
def test_structure_is_blenders_exporters(key, blender):
    ours_top, ours_defs, ours_objs, ours_counted = structure(blender["ours"][key])
    ref_top, ref_defs, ref_objs, ref_counted = structure(
        blender["ours"][key].parent / f"{key}_blender.fbx")
    assert ours_top == ref_top == SECTIONS
    for defs, counted in ((ours_defs, ours_counted), (ref_defs, ref_counted)):
        assert {k: v[0] for k, v in defs.items() if k != "GlobalSettings"} == dict(counted)
    assert set(ref_defs) <= set(ours_defs) <= set(ref_defs) | {"Pose"}
    for kind in set(ref_defs) & set(ours_defs):
        ours_template, ref_template = ours_defs[kind][1:], ref_defs[kind][1:]
        if ref_template[0] is not None:
            assert ours_template[0] == ref_template[0], kind
            assert ours_template[1] <= ref_template[1], kind
    for objects in (ours_objs, ref_objs):
        assert ("Model", "LimbNode") in objects
    ours_limbs = [o for o in parse_binary(blender["ours"][key].read_bytes()).walk()
                  if o.name == "Model" and class_of(o) == "LimbNode"]
    ref_limbs = [o for o in parse_binary((blender["ours"][key].parent /
                                          f"{key}_blender.fbx").read_bytes()).walk()
                 if o.name == "Model" and class_of(o) == "LimbNode"]
    assert sorted(map(name_of, ours_limbs)) == sorted(map(name_of, ref_limbs))
    assert set(ours_objs) == set(ref_objs) - BLENDER_ONLY | (
        {("Pose", "BindPose")} if key == "walk" else set())
    for kind in set(ours_objs) & set(ref_objs):
        ours_records, ours_ps = ours_objs[kind]
        ref_records, ref_ps = ref_objs[kind]
        assert ours_records == ref_records - {"Edges"}, kind            # Edges: derived
        allowed = BLENDER_ONLY_PROPS | (BLENDER_ONLY_MESH_PROPS if kind == ("Model", "Mesh")
                                        else set())
        assert ref_ps - allowed <= ours_ps, kind


# --------------------------------------------------------------------------- the commands
def cli(capsys, *argv):
    from motion_composer.app.cli import main
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def skinned_fbx_summary(path) -> dict:
    tree = parse_binary(path.read_bytes())
    objects = tree.find("Objects").children
    return {"joints": sorted(name_of(o) for o in objects
                             if o.name == "Model" and class_of(o) == "LimbNode"),
            "meshes": sum(1 for o in objects if o.name == "Geometry"),
            "clusters": sum(1 for o in objects if o.name == "Deformer" and
                            class_of(o) == "Cluster"),
            "keys": len(key_times(tree))}


def test_retarget_and_export_write_fbx_with_the_characters_mesh(capsys, tmp_path,
                                                                test_character):
    out, project = tmp_path / "onto.fbx", tmp_path / "onto.mcp"
    code, stdout, err = cli(capsys, "retarget", clip_path("cmu_131_01_walk.bvh"), "--target",
                            TEST_CHARACTER, "--frames", "0:119", "-o", out,
                            "--save-project", project)
    assert code == 0, err
    assert f"wrote {out}" in stdout
    summary = skinned_fbx_summary(out)
    assert summary == {"joints": sorted(test_character.skeleton.names), "meshes": 1,
                       "clusters": summary["clusters"], "keys": 120}
    weighted = {j for m in test_character.meshes for j in np.unique(m.joints[m.weights > 0])}
    assert summary["clusters"] == len(weighted)
    again = tmp_path / "again.fbx"
    code, stdout, err = cli(capsys, "export", project, "-o", again, "--frames", "0:59")
    assert code == 0, err
    assert skinned_fbx_summary(again) == dict(summary, keys=60)


def test_rotation_only_is_refused_for_fbx(capsys, tmp_path):
    out = tmp_path / "walk.fbx"
    code, stdout, err = cli(capsys, "retarget", clip_path("cmu_131_01_walk.bvh"), "--target",
                            clip_path("cmu_rest_tpose.bvh"), "--frames", "0:9",
                            "--rotation-only", "-o", out)
    assert code == 2 and stdout == "" and err.count("\n") == 1
    assert "rotation-only channels are a BVH option" in err and "walk.fbx" in err
    assert not out.exists()
