"""Blender 3.4 writes the shared characters and a clip as other exporters would: a campaign's
file generator (run by hand; the tests that need one variant build it themselves).

Run::

    blender -b --factory-startup --python-exit-code 1 --python tests/blender_variants.py \
        -- OUT_FOLDER [SHARED_DATA]

It imports ``target_mixamo_ely.glb``, ``target_robot_expressive.glb`` and a BVH clip and
exports each with varied settings (FBX binary 7.4 with other axes, scales, leaf bones, bone
axes, node types, object transforms, actions; glTF as .glb and .gltf + .bin, Z up; BVH in
other rotation orders, scales and rates), and writes ``OUT_FOLDER/manifest.json``: per
variant its file, its source, what was changed and the similarity (scale, rotation about the
engine's +Y in degrees) that takes the source's joint world positions (engine axes, metres)
to the variant's, when the file states its axes and units (FBX, glTF); ``None`` for a BVH
file, whose axes and units the reader detects.
"""
import builtins
import json
import math
import os
import sys

import bpy
import numpy
from mathutils import Matrix

numpy.bool = bool       # Blender 3.4's glTF importer still names numpy.bool (gone in 1.24)

import io_anim_bvh.import_bvh as import_bvh  # noqa: E402

import_bvh.open = lambda f, mode="r", *a, **k: builtins.open(f, mode.replace("U", ""), *a, **k)

args = sys.argv[sys.argv.index("--") + 1:]
OUT = args[0]
DATA = args[1] if len(args) > 1 else "/work/shared/data"
os.makedirs(OUT, exist_ok=True)
manifest = []


def fresh():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def load(source, fps=None):
    """Import ``source`` into an empty scene; a BVH clip in metres (its centimetres scaled)."""
    fresh()
    path = os.path.join(DATA, source)
    if source.endswith(".bvh"):
        if fps is not None:
            bpy.context.scene.render.fps = fps
        bpy.ops.import_anim.bvh(filepath=path, global_scale=0.01, frame_start=1,
                                use_fps_scale=fps is not None, update_scene_fps=fps is None,
                                update_scene_duration=True, rotate_mode="NATIVE")
    else:
        bpy.ops.import_scene.gltf(filepath=path)
    return armature()


def armature():
    arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    return arms[0]


def select_only(obj):
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def record(name, source, what, scale=1.0, turn=0.0, stated=True, **extra):
    manifest.append(dict(name=name, file=os.path.join(OUT, name), source=source, what=what,
                         scale=scale if stated else None, turn=turn if stated else None,
                         **extra))
    print("wrote", name, flush=True)


def fbx(name, source, what, scale=1.0, turn=0.0, prepare=None, **options):
    arm = load(source)
    if prepare:
        prepare(arm)
    opts = dict(bake_anim=True, add_leaf_bones=False)
    opts.update(options)
    bpy.ops.export_scene.fbx(filepath=os.path.join(OUT, name), **opts)
    record(name, source, what, scale, turn, options=options)


def gltf(name, source, what, scale=1.0, turn=0.0, prepare=None, **options):
    arm = load(source)
    if prepare:
        prepare(arm)
    bpy.ops.export_scene.gltf(filepath=os.path.join(OUT, name), **options)
    record(name, source, what, scale, turn, options=options)


def bvh(name, source, what, fps=None, prepare=None, **options):
    arm = load(source, fps=fps)
    if prepare:
        prepare(arm)
    select_only(arm)
    scene = bpy.context.scene
    opts = dict(frame_start=scene.frame_start, frame_end=scene.frame_end)
    opts.update(options)
    bpy.ops.export_anim.bvh(filepath=os.path.join(OUT, name), **opts)
    record(name, source, what, stated=False, options=options, fps=scene.render.fps)


def scaled(k):
    """The armature object scaled by ``k`` in the world (an imported armature may carry a
    scale of its own, e.g. Mixamo's 0.01: it is kept)."""
    def prepare(arm):
        arm.matrix_world = Matrix.Scale(k, 4) @ arm.matrix_world
    return prepare


def turned(deg):
    """The armature object turned by ``deg`` about the world's up (Blender's +Z, the
    engine's +Y) on top of its own transform."""
    def prepare(arm):
        arm.matrix_world = Matrix.Rotation(math.radians(deg), 4, "Z") @ arm.matrix_world
    return prepare


ELY, ROBOT, CLIP = "target_mixamo_ely.glb", "target_robot_expressive.glb", \
    "bandai1_walk_normal_001.bvh"

jobs = [
    # FBX: Blender's exporter with its options
    lambda: fbx("ely_default.fbx", ELY, "FBX defaults (-Z forward, Y up)"),
    lambda: fbx("ely_yfwd_zup.fbx", ELY, "axis Y forward, Z up", axis_forward="Y",
                axis_up="Z"),
    lambda: fbx("ely_xfwd_zup.fbx", ELY, "axis X forward, Z up", axis_forward="X",
                axis_up="Z"),
    lambda: fbx("ely_scale001.fbx", ELY, "global scale 0.01", scale=0.01, global_scale=0.01),
    lambda: fbx("ely_scale100.fbx", ELY, "global scale 100", scale=100.0, global_scale=100.0),
    lambda: fbx("ely_no_unit_scale.fbx", ELY, "apply unit scale off", apply_unit_scale=False),
    lambda: fbx("ely_scale_all.fbx", ELY, "apply scalings FBX_SCALE_ALL",
                apply_scale_options="FBX_SCALE_ALL"),
    lambda: fbx("ely_leaf.fbx", ELY, "add leaf bones", add_leaf_bones=True),
    lambda: fbx("ely_boneaxis_x.fbx", ELY, "primary bone axis X, secondary -Y",
                primary_bone_axis="X", secondary_bone_axis="-Y"),
    lambda: fbx("ely_root_node.fbx", ELY, "armature node type ROOT", armature_nodetype="ROOT"),
    lambda: fbx("ely_limbnode.fbx", ELY, "armature node type LIMBNODE",
                armature_nodetype="LIMBNODE"),
    lambda: fbx("ely_objscale2.fbx", ELY, "armature object scale 2", scale=2.0,
                prepare=scaled(2.0)),
    lambda: fbx("ely_objturn90.fbx", ELY, "armature object turned 90 deg about up", turn=90.0,
                prepare=turned(90.0)),
    lambda: fbx("ely_bake_space.fbx", ELY, "apply transform (bake space), Z up",
                bake_space_transform=True, axis_forward="Y", axis_up="Z"),
    lambda: fbx("robot_default.fbx", ROBOT, "FBX defaults, all actions"),
    lambda: fbx("robot_one_action.fbx", ROBOT, "one action (all actions off, NLA off)",
                bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False),
    lambda: fbx("robot_zup_cm.fbx", ROBOT, "Z up, global scale 100", scale=100.0,
                axis_forward="Y", axis_up="Z", global_scale=100.0),
    lambda: fbx("robot_leaf_xaxis.fbx", ROBOT, "leaf bones, primary bone axis X",
                add_leaf_bones=True, primary_bone_axis="X", secondary_bone_axis="Y"),
    lambda: fbx("clip_default.fbx", CLIP, "a BVH clip as FBX"),
    lambda: fbx("clip_zup_leaf.fbx", CLIP, "clip: Z up, leaf bones", axis_forward="Y",
                axis_up="Z", add_leaf_bones=True),
    lambda: fbx("clip_objscale.fbx", CLIP, "clip: object scale 0.5 turned 90", scale=0.5,
                turn=90.0, prepare=lambda a: (scaled(0.5)(a), turned(90.0)(a))),
    # glTF
    lambda: gltf("ely.glb", ELY, "glb defaults", export_format="GLB"),
    lambda: gltf("ely_sep.gltf", ELY, ".gltf + .bin", export_format="GLTF_SEPARATE"),
    lambda: gltf("ely_zup.glb", ELY, "export +Y up off (Z up file)", export_format="GLB",
                 export_yup=False),
    lambda: gltf("robot.glb", ROBOT, "glb defaults", export_format="GLB"),
    lambda: gltf("robot_objscale.gltf", ROBOT, "object scale 2, .gltf + .bin", scale=2.0,
                 prepare=scaled(2.0), export_format="GLTF_SEPARATE"),
    lambda: gltf("clip.glb", CLIP, "a BVH clip as glb", export_format="GLB"),
    lambda: gltf("ely_embedded.gltf", ELY, ".gltf with embedded (data: URI) buffers",
                 export_format="GLTF_EMBEDDED"),
    lambda: gltf("ely_draco.glb", ELY, "Draco-compressed meshes", export_format="GLB",
                 export_draco_mesh_compression_enable=True),
    lambda: gltf("ely_no_skin.glb", ELY, "skins off (meshes not skinned)",
                 export_format="GLB", export_skins=False),
    lambda: gltf("ely_bare_mesh.glb", ELY, "no normals, no texture coordinates",
                 export_format="GLB", export_normals=False, export_texcoords=False),
    lambda: gltf("ely_def_bones.glb", ELY, "deform bones only", export_format="GLB",
                 export_def_bones=True),
    lambda: gltf("clip_curves.glb", CLIP, "keys not sampled (Bezier curves)",
                 export_format="GLB", export_force_sampling=False),
    lambda: gltf("robot_curves.gltf", ROBOT, "keys not sampled, .gltf + .bin",
                 export_format="GLTF_SEPARATE", export_force_sampling=False),
    lambda: gltf("ely_no_anim.glb", ELY, "animations off", export_format="GLB",
                 export_animations=False),
    lambda: fbx("ely_no_anim.fbx", ELY, "bake animation off", bake_anim=False),
    lambda: fbx("ely_deform_only.fbx", ELY, "deform bones only",
                use_armature_deform_only=True),
    lambda: fbx("ely_armature_only.fbx", ELY, "armature only (no mesh)",
                object_types={"ARMATURE"}),
    lambda: fbx("clip_step2.fbx", CLIP, "bake step 2, simplify 0", bake_anim_step=2.0,
                bake_anim_simplify_factor=0.0),
    lambda: fbx("robot_nla.fbx", ROBOT, "NLA strips on, all actions off",
                bake_anim_use_all_actions=False, bake_anim_use_nla_strips=True),
    # BVH
    lambda: bvh("clip_native.bvh", CLIP, "Blender BVH export (Z up, metres)"),
    lambda: bvh("clip_zxy.bvh", CLIP, "rotation order ZXY", rotate_mode="ZXY"),
    lambda: bvh("clip_xyz.bvh", CLIP, "rotation order XYZ", rotate_mode="XYZ"),
    lambda: bvh("clip_cm.bvh", CLIP, "global scale 100 (centimetres)", global_scale=100.0),
    lambda: bvh("clip_24fps.bvh", CLIP, "retimed to 24 fps", fps=24),
    lambda: bvh("clip_25fps.bvh", CLIP, "retimed to 25 fps", fps=25),
    lambda: bvh("clip_60fps.bvh", CLIP, "retimed to 60 fps", fps=60),
    lambda: bvh("clip_root_only.bvh", CLIP, "root transform only", root_transform_only=True),
    lambda: bvh("robot.bvh", ROBOT, "robot character's action as BVH"),
    lambda: bvh("ely.bvh", ELY, "Ely's action as BVH"),
]

for job in jobs:
    try:
        job()
    except Exception as exc:      # one failed export must not stop the others
        print("FAILED", repr(exc), flush=True)
        manifest.append(dict(name=None, error=repr(exc)))

# retimed clips as FBX and glTF (the scene's rate goes into the file)
for name, rate in (("clip_24fps.fbx", 24), ("clip_60fps.fbx", 60), ("clip_25fps.glb", 25)):
    try:
        load(CLIP, fps=rate)
        if name.endswith(".fbx"):
            bpy.ops.export_scene.fbx(filepath=os.path.join(OUT, name), bake_anim=True,
                                     add_leaf_bones=False)
        else:
            bpy.ops.export_scene.gltf(filepath=os.path.join(OUT, name), export_format="GLB")
        record(name, CLIP, f"clip retimed to {rate} fps", fps=rate)
    except Exception as exc:
        print("FAILED", repr(exc), flush=True)

json.dump(manifest, open(os.path.join(OUT, "manifest.json"), "w"), indent=1,
          default=sorted)
