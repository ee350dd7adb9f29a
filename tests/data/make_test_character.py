"""Makes ``test_character.glb``: a small skinned glTF character made by our own code, so that
glTF reading, skinning, export and the window's skinned drawing are tested without
``../shared``.

    python tests/data/make_test_character.py      # from the repository's root

The skeleton is the bundled CMU T-pose's (``resources/clips/cmu_rest_tpose.bvh``, 31 joints,
metres, +Y up). The mesh is one box around each bone longer than 3 cm (from a joint to its
child, or to its End Site), 24 vertices with face normals per box; the vertices at a bone's
start follow its joint alone (weight 1), those at its far end are shared half and half with
the child joint, so that bending a joint stretches the box across it as a skin does. The
animation, ``Swing``, is one second at 30 fps: the legs and arms swing in opposite phase and
the hips move forward 0.3 m. The file is written with :func:`engine.formats.gltf.write_gltf`
(one pass skeleton-only, read back for a :class:`~engine.formats.gltf.Character`, then written
again with the mesh), to ``tests/data/test_character.glb`` and, for the installed program's
self-test, ``resources/characters/test_character.glb``; the output is the same byte for byte
at each run.
"""
from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(REPO))

from motion_composer.engine import Motion, read_bvh  # noqa: E402
from motion_composer.engine.formats.gltf import Mesh, read_gltf, write_gltf  # noqa: E402

SKELETON = REPO / "resources" / "clips" / "cmu_rest_tpose.bvh"
OUTPUTS = (REPO / "tests" / "data" / "test_character.glb",
           REPO / "resources" / "characters" / "test_character.glb")
NAME = "test_character"
ANIMATION = "Swing"
FPS = 30
FRAMES = 30
#: bones shorter than this [m] get no box (the CMU hip and shoulder joints sit on each other)
MIN_BONE = 0.03
#: box half-width as a fraction of the bone's length, and its bounds [m]
WIDTH = 0.18
MIN_HALF, MAX_HALF = 0.012, 0.06
#: swing amplitude [rad] per joint name, and the axis (internal, +Y up, +Z forward)
SWING = {"LeftUpLeg": (0.5, (1, 0, 0)), "RightUpLeg": (-0.5, (1, 0, 0)),
         "LeftLeg": (0.6, (1, 0, 0)), "RightLeg": (0.6, (1, 0, 0)),
         "LeftArm": (0.5, (0, 1, 0)), "RightArm": (0.5, (0, 1, 0)),
         "LeftForeArm": (0.4, (0, 1, 0)), "RightForeArm": (-0.4, (0, 1, 0))}
#: the unit cube's faces: outward normal and the four corners (signs along u, v, w), counter-
#: clockwise seen from outside
_FACES = [((1, 0, 0), [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)]),
          ((-1, 0, 0), [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)]),
          ((0, 1, 0), [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)]),
          ((0, -1, 0), [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)]),
          ((0, 0, 1), [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]),
          ((0, 0, -1), [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)])]


def bones(skeleton) -> list[tuple[int, int | None, np.ndarray, np.ndarray]]:
    """``(joint, child or None, start, end)`` per bone to dress: world positions [m] of the
    T-pose (zero rotations), one bone per child joint or End Site."""
    world = np.zeros((skeleton.num_joints, 3))
    for j in range(skeleton.num_joints):
        p = skeleton.parents[j]
        world[j] = skeleton.offsets[j] + (world[p] if p >= 0 else 0.0)
    out = []
    for j in range(1, skeleton.num_joints):
        p = skeleton.parents[j]
        out.append((p, j, world[p], world[j]))
    for site in skeleton.end_sites:
        out.append((site.parent, None, world[site.parent], world[site.parent] + site.offset))
    return [b for b in out if np.linalg.norm(b[3] - b[2]) >= MIN_BONE]


def box(start: np.ndarray, end: np.ndarray):
    """A box from ``start`` to ``end`` [m]: ``(24, 3)`` positions, ``(24, 3)`` normals,
    ``(12, 3)`` triangles, ``(24,)`` whether each vertex is at the far end."""
    axis = end - start
    length = float(np.linalg.norm(axis))
    w = axis / length
    helper = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    half = float(np.clip(WIDTH * length, MIN_HALF, MAX_HALF))
    frame = np.stack([u, v, w])                        # rows: the box's axes in the world
    positions, normals, far, triangles = [], [], [], []
    for normal, corners in _FACES:
        base = len(positions)
        for su, sv, sw in corners:
            local = np.array([su * half, sv * half, (sw + 1) * 0.5 * length])
            positions.append(start + local @ frame)
            normals.append(np.asarray(normal, dtype=float) @ frame)
            far.append(sw > 0)
        triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return (np.array(positions), np.array(normals), np.array(triangles, dtype=np.int64),
            np.array(far))


def mesh(skeleton) -> Mesh:
    """The boxes of every bone as one skinned mesh (two influences per vertex)."""
    positions, normals, triangles, joints, weights = [], [], [], [], []
    count = 0
    for joint, child, start, end in bones(skeleton):
        p, n, t, far = box(start, end)
        positions.append(p)
        normals.append(n)
        triangles.append(t + count)
        count += len(p)
        shared = far & (child is not None)
        jj = np.stack([np.full(len(p), joint), np.where(shared, child or 0, 0)], axis=1)
        ww = np.stack([np.where(shared, 0.5, 1.0), np.where(shared, 0.5, 0.0)], axis=1)
        joints.append(jj)
        weights.append(ww)
    return Mesh(name="body", positions=np.concatenate(positions),
                normals=np.concatenate(normals), triangles=np.concatenate(triangles),
                joints=np.concatenate(joints).astype(np.int64),
                weights=np.concatenate(weights), skin=0, node=0)


def swing(skeleton) -> Motion:
    """``Swing``: one second of legs and arms swinging, the hips moving forward."""
    phase = np.sin(2.0 * np.pi * np.arange(FRAMES) / FRAMES)
    rotations = np.zeros((FRAMES, skeleton.num_joints, 4))
    rotations[..., 3] = 1.0
    for name, (amplitude, axis) in SWING.items():
        j = skeleton.index[name]
        angle = amplitude * phase if "Leg" not in name or "Up" in name \
            else amplitude * np.maximum(phase, 0.0)                  # knees bend one way
        rotations[:, j, :3] = np.sin(angle / 2)[:, None] * np.asarray(axis, dtype=float)
        rotations[:, j, 3] = np.cos(angle / 2)
    translations = np.repeat(skeleton.offsets[skeleton.translated][None], FRAMES, axis=0)
    translations[:, 0, 2] += np.linspace(0.0, 0.3, FRAMES)
    return Motion(skeleton, rotations, translations, 1.0 / FPS, name=ANIMATION)


def build(outputs=OUTPUTS) -> None:
    skeleton = read_bvh(SKELETON).skeleton
    motion = swing(skeleton)
    with tempfile.TemporaryDirectory() as scratch:
        bare = Path(scratch) / f"{NAME}.glb"
        write_gltf(motion, None, bare)
        character = dataclasses.replace(read_gltf(bare), meshes=(mesh(skeleton),))
    motion = dataclasses.replace(motion, skeleton=character.skeleton)
    for out in outputs:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_gltf(motion, character, out, name=ANIMATION)
        print(f"{out}: {out.stat().st_size} bytes, "
              f"{character.skeleton.num_joints} joints, {character.num_vertices} vertices, "
              f"{character.num_triangles} triangles")


if __name__ == "__main__":
    build()
