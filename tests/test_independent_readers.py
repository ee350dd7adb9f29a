"""Our BVH output, read by readers we did not write: bvhio (PyPI) and Blender's importer.

For every BVH file we have, the motion is read by the engine and written with write_bvh to a
temporary folder; the independent reader loads that file, and the world joint positions it
computes must equal our forward kinematics (converted back to the file's units and axes with
``skeleton.source.points_to_file``) within 1e-4 of the body's height.

Conventions of the two readers, found in their sources:

* bvhio 1.5.4 (``bvhio/lib/Parser.py``, ``_deserializeMotion``): a joint's local position
  starts as its OFFSET and each position channel *overwrites* its axis, for the root and any
  other joint alike: position channels are "absolute" (they replace the OFFSET). Rotations are
  intrinsic in channel order (``Euler.toQuatFrom(..., extrinsic=False)``), in float32 (glm).
* Blender 3.4 (``io_anim_bvh/import_bvh.py``): a joint with position channels gets the pose
  location ``channel values - rest_head_local`` in its rest frame, so its head lands on the
  channel values: "absolute" again, root and non-root. Rotations: ``Euler(angles,
  order[::-1])`` (Blender's extrinsic reading of the reversed order, i.e. R = R1 R2 R3).
  Blender keeps the first file frame at scene frame ``frame_start`` (1 by default; its own
  frame 0 rest entry is skipped), one file frame per scene frame (``use_fps_scale`` off),
  linear keys. ``axis_forward='Y', axis_up='Z'`` makes its axis conversion the identity.

Our files with "relative" position channels (the CC3 hip-rooted clip, whose root channels add to
its OFFSET) are therefore written for these readers with ``position_modes`` set to "absolute"
for those joints: the same motion, in the convention the independent reader uses. Bandai's
non-root position channels are already "absolute". ``test_bvhio_reads_position_channels_as_
absolute`` shows that writing "relative" channels instead does make bvhio disagree.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from blender_util import blender_or_skip, run_blender_import
from conftest import BUNDLED_BVH, SHARED_BVH, SHARED_DATA, all_bvh_params, resolve
from motion_composer.engine.formats.bvh import read_bvh, write_bvh
from motion_composer.engine.describe import stature
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.motion import Motion

bvhio = pytest.importorskip("bvhio")

#: a fraction of the body height (float32 readers: ~1e-7 of the extent is their noise floor)
REL_TOL = 1e-4
#: files with at most this many frames are compared at every frame
ALL_FRAMES_UP_TO = 200
#: otherwise first, middle, last and this many frames spread between
SAMPLES = 12


def _frames(n: int) -> list[int]:
    if n <= ALL_FRAMES_UP_TO:
        return list(range(n))
    spread = np.linspace(0, n - 1, SAMPLES).round().astype(int)
    return sorted({0, n // 2, n - 1, *spread.tolist()})


def _reader_modes(motion: Motion) -> dict[str, str] | None:
    """position_modes for format_bvh that write every position channel as "absolute" (replacing
    the OFFSET), the convention bvhio and Blender read; None when the file already is."""
    sk = motion.skeleton
    change = {sk.names[j]: "absolute" for j, m in enumerate(sk.position_modes)
              if m == "relative"}
    return change or None


@dataclass
class Written:
    name: str
    motion: Motion         # the original file, read by the engine
    out: Path              # our output, in the readers' position convention
    world_file: np.ndarray  # (F, J, 3) our FK world positions, file units and axes
    tol: float             # REL_TOL of the body height, file units
    modes_changed: dict | None


def _write(spec, folder: Path) -> Written:
    path = resolve(spec)
    motion = read_bvh(path)
    modes = _reader_modes(motion)
    out = folder / (spec[0] + "_" + path.name)
    write_bvh(motion, out, position_modes=modes)
    src = motion.skeleton.source
    world = src.points_to_file(forward_kinematics(motion, end_sites=False).positions)
    tol = REL_TOL * stature(motion) / src.scale
    return Written(path.name, motion, out, world, tol, modes)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    folder = tmp_path_factory.mktemp("independent")
    cache: dict = {}

    def get(spec) -> Written:
        if spec not in cache:
            cache[spec] = _write(spec, folder)
        return cache[spec]

    return get


def test_reader_convention_is_applied_where_needed():
    """The CC3 hip-rooted clip is the one whose root channels are relative: it is the one
    rewritten (skips without ../shared/data)."""
    from conftest import shared_path
    motion = read_bvh(shared_path("cc3_cmu_02_06_pickup.bvh"))
    assert _reader_modes(motion) == {"CC_Base_Hip": "absolute"}
    assert _reader_modes(read_bvh(shared_path("bandai1_walk_normal_001.bvh"))) is None


# ----------------------------------------------------------------------------------- bvhio
def _bvhio_world(path: Path, names, frames) -> np.ndarray:
    root = bvhio.readAsHierarchy(str(path))
    joints = {j.Name: j for j, _, _ in root.layout()}
    assert sorted(joints) == sorted(names)
    out = np.empty((len(frames), len(names), 3))
    for k, f in enumerate(frames):
        root.loadPose(f, recursive=True)
        out[k] = [tuple(joints[n].PositionWorld) for n in names]
    return out


@pytest.mark.parametrize("spec", all_bvh_params())
def test_bvhio_reads_our_output_to_the_same_world(spec, written):
    w = written(spec)
    frames = _frames(w.motion.num_frames)
    theirs = _bvhio_world(w.out, w.motion.skeleton.names, frames)
    err = np.abs(theirs - w.world_file[frames]).max()
    assert err <= w.tol, f"{w.name}: bvhio differs by {err:.3g} file units (tol {w.tol:.3g})"


def test_bvhio_reads_position_channels_as_absolute(tmp_path):
    """Written the other way ("relative": channel + OFFSET), bvhio puts the joints off by
    exactly their OFFSETs, which shows its convention: root (CC3) and non-root (Bandai)."""
    from conftest import shared_path
    for name, joint in (("cc3_cmu_02_06_pickup.bvh", "CC_Base_Hip"),
                        ("bandai1_run_active_001.bvh", "Hips")):
        motion = read_bvh(shared_path(name))
        if name.startswith("cc3"):
            motion = motion.frames(slice(0, 30))
        sk = motion.skeleton
        out = tmp_path / name
        write_bvh(motion, out, position_modes="relative")
        j = sk.joint(joint)
        world = sk.source.points_to_file(forward_kinematics(motion).positions)
        theirs = _bvhio_world(out, sk.names, [0])[0]
        off = sk.offsets[j] / sk.source.scale
        assert np.linalg.norm(off) > 1.0
        # the joint itself is displaced by minus its OFFSET, rotated into the world
        gap = np.linalg.norm(theirs[j] - world[0, j])
        assert abs(gap - np.linalg.norm(off)) < 1e-3, (name, gap, off)


# ---------------------------------------------------------------------------------- Blender
def _available_specs():
    specs = [("bundled", n) for n in BUNDLED_BVH]
    if SHARED_DATA.is_dir():
        specs += [("shared", n) for n in SHARED_BVH if (SHARED_DATA / n).is_file()]
    return specs


@pytest.fixture(scope="module")
def blender_results(written, tmp_path_factory):
    blender_or_skip()
    folder = tmp_path_factory.mktemp("blender")
    files = []
    for spec in _available_specs():
        w = written(spec)
        files.append({"key": f"{spec[0]}/{spec[1]}", "path": str(w.out),
                      "frames": _frames(w.motion.num_frames)})
    return run_blender_import(files, folder)


@pytest.mark.blender
@pytest.mark.parametrize("spec", all_bvh_params())
def test_blender_reads_our_output_to_the_same_world(spec, written, blender_results):
    w = written(spec)
    res = blender_results[f"{spec[0]}/{spec[1]}"]
    np.testing.assert_array_equal(res["matrix_world"], np.eye(4))   # no axis conversion
    F = w.motion.num_frames
    assert res["keys_per_curve"] == [F]           # one key per file frame...
    assert res["first_key_frame"] == [1.0]        # ...starting at scene frame 1
    names = w.motion.skeleton.names
    frames = _frames(F)
    theirs = np.array([[res["positions"][str(f)][n] for n in names] for f in frames])
    err = np.abs(theirs - w.world_file[frames]).max()
    assert err <= w.tol, f"{w.name}: Blender differs by {err:.3g} file units (tol {w.tol:.3g})"
