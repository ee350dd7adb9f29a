"""Blender as an independent BVH reader, shared by the tests that use it.

:func:`run_blender_import` starts Debian's Blender (3.4) headless once, imports every listed BVH
file with its own importer (``io_anim_bvh``) and reports, per file, the world position of every
pose bone's head at the requested file frames, the armature's world matrix, the number of keys
per animation curve and the scene frame of the first key.

Importer settings (see ``io_anim_bvh/import_bvh.py``): ``axis_forward='Y', axis_up='Z'`` make
its axis conversion the identity and ``global_scale=1`` keeps the file's units, so the
positions are in the file's own units and axes; ``frame_start=1`` puts file frame ``f``
(counted from 0) at scene frame ``f + 1``; ``use_fps_scale`` off gives one scene frame per file
frame. Blender reads every position channel as "absolute" (it replaces the OFFSET) and
rotations as R = R1 R2 R3 in channel order.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import textwrap
from pathlib import Path

import pytest

#: what every BVH script starts with: the job, and Blender's BVH importer made to open files
BVH_PROLOGUE = textwrap.dedent(r'''
    import builtins, json, sys
    import bpy
    import io_anim_bvh.import_bvh as import_bvh

    # Blender 3.4's importer opens files with mode 'rU', which Python 3.11 refuses
    def _open(file, mode="r", *args, **kwargs):
        return builtins.open(file, mode.replace("U", ""), *args, **kwargs)
    import_bvh.open = _open

    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    def import_file(path):
        """The armature Blender's importer makes of a BVH file, in its own units and axes."""
        before = set(bpy.data.objects)
        bpy.ops.import_anim.bvh(filepath=path, target="ARMATURE", global_scale=1.0,
                                rotate_mode="NATIVE", axis_forward="Y", axis_up="Z",
                                frame_start=1, use_fps_scale=False, use_cyclic=False,
                                update_scene_fps=False, update_scene_duration=False)
        new = [o for o in bpy.data.objects if o not in before]
        assert len(new) == 1 and new[0].type == "ARMATURE", new
        return new[0]
''')

BLENDER_SCRIPT = BVH_PROLOGUE + textwrap.dedent(r'''
    results = {}
    scene = bpy.context.scene
    for item in job["files"]:
        arm = import_file(item["path"])
        action = arm.animation_data.action
        keys = sorted({len(c.keyframe_points) for c in action.fcurves})
        first = sorted({c.keyframe_points[0].co[0] for c in action.fcurves})
        positions = {}
        for f in item["frames"]:
            scene.frame_set(f + 1)          # file frame f (from 0) is scene frame f + 1
            positions[f] = {pb.name: list(arm.matrix_world @ pb.head) for pb in arm.pose.bones}
        results[item["key"]] = {"keys_per_curve": keys, "first_key_frame": first,
                                "matrix_world": [list(r) for r in arm.matrix_world],
                                "positions": positions}
        bpy.data.objects.remove(arm, do_unlink=True)   # keep later frame_set calls cheap
        bpy.data.actions.remove(action)
    json.dump(results, open(job["out"], "w"))
''')


def blender_or_skip() -> str:
    """The ``blender`` executable, or skip the test saying why."""
    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("Blender is not installed (no 'blender' on PATH); the Debian package "
                    "'blender' provides the independent BVH importer this test uses")
    return blender


def run_blender(script_text: str, script_name: str, job: dict, folder: Path,
                timeout: float = 300) -> dict:
    """Run ``script_text`` in headless Blender with ``job`` (a dict, given ``out``: where the
    script writes its JSON result) and return that result; raises AssertionError with
    Blender's output when it fails."""
    blender = blender_or_skip()
    folder = Path(folder)
    script = folder / script_name
    script.write_text(script_text)
    out = folder / "result.json"
    job_file = folder / "job.json"
    job_file.write_text(json.dumps(dict(job, out=str(out))))
    # Debian's Blender embeds the system Python and finds its home from the first python3 on
    # PATH: behind pyenv's shims it would take pyenv's standard library and miss
    # /usr/lib/python3/dist-packages, where the numpy its glTF add-on needs lives
    path = os.pathsep.join([os.path.dirname(os.path.realpath(blender)),
                            os.environ.get("PATH", "")])
    env = dict(os.environ, PYTHONNOUSERSITE="1", PATH=path)
    proc = subprocess.run([blender, "-b", "--factory-startup", "--python-exit-code", "1",
                           "--python", str(script), "--", str(job_file)],
                          capture_output=True, text=True, timeout=timeout, env=env)
    if proc.returncode != 0 or not out.is_file():
        raise AssertionError(f"Blender failed (exit {proc.returncode}):\n"
                             f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return json.loads(out.read_text())


def run_blender_import(files: list[dict], folder: Path, timeout: float = 300) -> dict:
    """Import BVH files in one headless Blender process.

    Args:
        files: ``{"key": str, "path": str, "frames": [int, ...]}`` per file (frames counted
            from 0, as in the file).
        folder: where the script, the job and the result are written.

    Returns:
        key -> ``{"keys_per_curve": [...], "first_key_frame": [...], "matrix_world": 4x4,
        "positions": {str(frame): {bone name: [x, y, z]}}}`` (JSON turns the frame keys into
        strings).
    """
    return run_blender(BLENDER_SCRIPT, "read_bvh_in_blender.py", {"files": files}, folder,
                       timeout)


ROUNDTRIP_SCRIPT = BVH_PROLOGUE + textwrap.dedent(r'''
    for item in job["files"]:
        arm = import_file(item["path"])
        action = arm.animation_data.action
        bpy.ops.object.select_all(action="DESELECT")
        arm.select_set(True)
        bpy.context.view_layer.objects.active = arm
        bpy.ops.export_anim.bvh(filepath=item["out"], frame_start=1,
                                frame_end=item["frames"], global_scale=1.0,
                                rotate_mode="NATIVE", root_transform_only=False)
        bpy.data.objects.remove(arm, do_unlink=True)
        bpy.data.actions.remove(action)
    json.dump({"exported": len(job["files"])}, open(job["out"], "w"))
''')


def run_blender_roundtrip(files: list[dict], folder: Path, timeout: float = 600) -> None:
    """Import each BVH file with Blender's importer and export it again with its exporter, in
    one headless Blender process; ``files``: ``{"path": str, "out": str, "frames": int}``."""
    run_blender(ROUNDTRIP_SCRIPT, "roundtrip_bvh_in_blender.py", {"files": files}, folder,
                timeout)


# ------------------------------------------------------------------------------------- FBX
FBX_SCRIPT = textwrap.dedent(r'''
    import json, math, sys
    import numpy
    import bpy

    numpy.bool = bool       # Blender 3.4's glTF importer still names numpy.bool (gone in 1.24)

    job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
    results = {"imports": {}, "exports": {}}
    for item in job.get("exports", []):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        if item["source"].endswith(".bvh"):
            import builtins
            import io_anim_bvh.import_bvh as import_bvh
            import_bvh.open = lambda f, mode="r", *a, **k: builtins.open(
                f, mode.replace("U", ""), *a, **k)
            bpy.ops.import_anim.bvh(filepath=item["source"], global_scale=1.0)
        else:
            bpy.ops.import_scene.gltf(filepath=item["source"])
        options = dict(bake_anim=True, add_leaf_bones=False)
        options.update(item.get("options", {}))
        bpy.ops.export_scene.fbx(filepath=item["out"], **options)
        results["exports"][item["key"]] = item["out"]
    for item in job.get("imports", []):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_scene.fbx(filepath=item["path"])
        scene = bpy.context.scene
        armatures = [o for o in scene.objects if o.type == "ARMATURE"]
        arm = armatures[0]
        # the importer connects bones, which drops their translation: undo that
        bpy.context.view_layer.objects.active = arm
        bpy.ops.object.mode_set(mode="EDIT")
        for bone in arm.data.edit_bones:
            bone.use_connect = False
        bpy.ops.object.mode_set(mode="OBJECT")
        meshes = [o for o in scene.objects if o.type == "MESH"]
        out = {"armatures": len(armatures), "fps": scene.render.fps / scene.render.fps_base,
               "scene_fps": scene.render.fps, "positions": [], "meshes": {}}
        for o in meshes:
            sizes = [0] * len(o.vertex_groups)
            for v in o.data.vertices:
                for e in v.groups:
                    sizes[e.group] += e.weight > 0
            out["meshes"][o.name] = {"groups": sorted(g.name for g in o.vertex_groups),
                                     "group_sizes": {g.name: sizes[g.index]
                                                     for g in o.vertex_groups},
                                     "vertices": len(o.data.vertices), "skinned": {}}
        for k, f in enumerate(item["frames"]):
            scene.frame_set(math.floor(f), subframe=f - math.floor(f))
            out["positions"].append({pb.name: list(arm.matrix_world @ pb.head)
                                     for pb in arm.pose.bones})
            if k in item.get("skin_at", []):
                depsgraph = bpy.context.evaluated_depsgraph_get()
                for o in meshes:
                    evaluated = o.evaluated_get(depsgraph)
                    mesh = evaluated.to_mesh()
                    out["meshes"][o.name]["skinned"][k] = [list(o.matrix_world @ v.co)
                                                           for v in mesh.vertices]
                    evaluated.to_mesh_clear()
        results["imports"][item["key"]] = out
    json.dump(results, open(job["out"], "w"))
''')


def run_blender_fbx(job: dict, folder: Path, timeout: float = 300) -> dict:
    """One headless Blender process that exports FBX with Blender's own exporter and imports
    FBX files with its importer (``io_scene_fbx``, default settings).

    Args:
        job: ``{"exports": [{"key", "source": a .bvh or .glb, "out": an .fbx path,
            "options": the exporter's settings beside ``bake_anim`` on and
            ``add_leaf_bones`` off (optional)}],
            "imports": [{"key", "path": an .fbx, "frames": [scene frame (may be fractional),
            ...], "skin_at": [indices into frames where the skinned vertices are reported]}]}``.
        folder: where the script, the job and the result are written.

    Returns:
        ``{"exports": {key: path}, "imports": {key: {"armatures": count, "fps": the file's
        rate, "scene_fps": the scene's (whole) rate, "positions": [{bone: [x, y, z]} per
        frame], "meshes": {name: {"groups": [vertex group names], "group_sizes": {group:
        vertex count}, "vertices": count, "skinned": {str(index): [[x, y, z], ...]}}}}}}``,
        positions in Blender's world (metres, +Z up) with the bones' ``use_connect`` switched
        off after import. Blender puts FBX time ``t`` at scene frame ``t * scene_fps + 1``.
    """
    return run_blender(FBX_SCRIPT, "fbx_in_blender.py", job, folder, timeout)
