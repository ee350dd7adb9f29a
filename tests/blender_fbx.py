"""Blender as an independent FBX reader, shared by the tests that use it.

:func:`run_blender_fbx` starts Debian's Blender (3.4) headless once and imports every listed
FBX file with its own importer (``io_scene_fbx``, default settings: the file's axes and
``UnitScaleFactor`` to Blender's metres, +Z up). Per file it reports the world position of
every bone's head in the bind pose (edit bones) and, per requested take, at the requested
times (and, when asked, every mesh's skinned vertices, as Blender's armature modifier deforms
them); ``None`` as a take is the pose without an action (the models' own transforms).

Blender's quirks, handled here (see ``shared/data/fbx/README.md``): its importer sets
``use_connect`` on bones whose head meets their parent's tail, which drops their translation;
it is switched off in edit mode after the import. Time ``t`` [s] is scene frame
``t * round(fps) + 1``; a time between frames is set as a subframe. Blender's axes are turned
into the engine's by :func:`engine_axes` (x, y, z) -> (x, z, -y).
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from blender_util import run_blender

BLENDER_SCRIPT = textwrap.dedent(r'''
    import json, math, sys
    import bpy

    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    results = {}
    for item in job["files"]:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_scene.fbx(filepath=item["path"])
        scene = bpy.context.scene
        arms = [o for o in scene.objects if o.type == "ARMATURE"]
        for arm in arms:
            bpy.context.view_layer.objects.active = arm
            bpy.ops.object.mode_set(mode="EDIT")
            for bone in arm.data.edit_bones:
                bone.use_connect = False
            bpy.ops.object.mode_set(mode="OBJECT")
        fps = round(scene.render.fps / scene.render.fps_base)
        bind = {b.name: list(arm.matrix_world @ b.head_local) for arm in arms
                for b in arm.data.bones}
        takes = {}
        for take, times in item["takes"]:
            for arm in arms:
                if arm.animation_data is None:
                    arm.animation_data_create()
                action = None
                if take is not None:
                    wanted = arm.name + "|" + take
                    action = next((a for a in bpy.data.actions if a.name == wanted or
                                   a.name.startswith(wanted + "|")), None)
                    assert action is not None, (wanted, [a.name for a in bpy.data.actions])
                arm.animation_data.action = action
            samples, meshes = [], []
            for t in times:
                frame = t * fps + 1
                whole = math.floor(frame + 1e-9)
                scene.frame_set(whole, subframe=max(0.0, frame - whole))
                samples.append({pb.name: list(arm.matrix_world @ pb.head) for arm in arms
                                for pb in arm.pose.bones})
                if item.get("meshes"):
                    graph = bpy.context.evaluated_depsgraph_get()
                    meshes.append({o.name: [list(o.matrix_world @ v.co) for v in
                                            o.evaluated_get(graph).to_mesh().vertices]
                                   for o in scene.objects if o.type == "MESH"})
            takes[str(take)] = samples
            if meshes:
                takes[str(take) + " meshes"] = meshes
        results[item["key"]] = {"fps": fps, "bind": bind, "takes": takes,
                                "actions": [a.name for a in bpy.data.actions]}
    json.dump(results, open(job["out"], "w"))
''')


def engine_axes(points) -> np.ndarray:
    """Blender's +Z-up world points ``(..., 3)`` in the engine's +Y-up axes."""
    p = np.asarray(points, dtype=float)
    return np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)


def run_blender_fbx(files: list[dict], folder: Path, timeout: float = 900) -> dict:
    """Import FBX files in one headless Blender process.

    Args:
        files: ``{"key": str, "path": str, "takes": [[take name or None, [t, ...]], ...],
            "meshes": bool}`` per file (times in seconds; ``meshes``: also the skinned
            vertices of every mesh object at those times).
        folder: where the script, the job and the result are written.

    Returns:
        key -> ``{"fps": int, "bind": {bone: [x, y, z]}, "takes": {str(take): [{bone:
        [x, y, z]} per time], str(take) + " meshes": [{mesh object: [[x, y, z] per
        vertex]} per time]}, "actions": [...]}`` in Blender's axes and metres.
    """
    return run_blender(BLENDER_SCRIPT, "read_fbx_in_blender.py", {"files": files}, folder,
                       timeout)
