"""Forward kinematics against an independent computation.

The reference below uses neither engine.quaternions nor engine.kinematics (nor the reader's
interpretation step): it builds 4x4 homogeneous matrices straight from the raw parsed record
(names, parents, OFFSETs, channel values in file units and file axes) with scipy's
``Rotation.from_euler`` in each joint's own channel order (upper case = intrinsic, the BVH
reading R = R1 R2 R3), applies position channels with the meaning the data's README documents
for each file, chains parent @ local, adds the End Sites, and only then converts to the engine's
internal metres / +Y with ``skeleton.source``.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import all_bvh_params, resolve
from motion_composer.engine.formats.bvh import (BVHRecord, detect_position_modes, parse_bvh_text,
                                                read_bvh)
from motion_composer.engine.describe import stature
from motion_composer.engine.kinematics import fk_arrays, forward_kinematics

#: position channels that ADD to the OFFSET, per file (from ../shared/data/README.md: the
#: CC3 hip-rooted export); everywhere else they replace it (roots, and every Bandai joint)
RELATIVE_JOINTS = {"cc3_cmu_02_06_pickup.bvh": {"CC_Base_Hip"}}
#: files with more frames than this are checked on an evenly spread sample of this many frames
MAX_FRAMES = 600


def _record(path) -> BVHRecord:
    return parse_bvh_text(path.read_bytes().decode("utf-8-sig"), path)


def _modes(name: str, record: BVHRecord) -> dict[str, str]:
    relative = RELATIVE_JOINTS.get(name, set())
    return {record.names[j]: ("relative" if record.names[j] in relative else "absolute")
            for j, chans in enumerate(record.channels) if any(c.endswith("position")
                                                              for c in chans)}


def reference_fk(record: BVHRecord, modes: dict[str, str], frames: np.ndarray):
    """World 4x4 matrices ``(J, F, 4, 4)`` and End Site points ``(E, F, 3)``, file units/axes."""
    values = record.values[frames]
    F = len(frames)
    J = len(record.names)
    world = np.empty((J, F, 4, 4))
    col = 0
    for j, chans in enumerate(record.channels):
        cols = dict(zip(chans, range(col, col + len(chans))))
        col += len(chans)
        local = np.broadcast_to(np.eye(4), (F, 4, 4)).copy()
        rot = [c for c in chans if c.endswith("rotation")]
        if rot:
            order = "".join(c[0] for c in rot)
            angles = values[:, [cols[c] for c in rot]]
            local[:, :3, :3] = Rotation.from_euler(order.upper(), angles,
                                                   degrees=True).as_matrix()
        t = np.broadcast_to(record.offsets[j], (F, 3)).copy()
        for axis, c in enumerate(("Xposition", "Yposition", "Zposition")):
            if c in cols:
                v = values[:, cols[c]]
                t[:, axis] = (t[:, axis] + v) if modes[record.names[j]] == "relative" else v
        local[:, :3, 3] = t
        p = record.parents[j]
        world[j] = local if p < 0 else world[p] @ local
    ends = np.empty((len(record.end_sites), F, 3))
    for e, (parent, offset) in enumerate(record.end_sites):
        ends[e] = (world[parent] @ np.append(offset, 1.0))[:, :3]
    return world, ends


def _frames(n: int) -> np.ndarray:
    if n <= MAX_FRAMES:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, MAX_FRAMES).round().astype(int))


@pytest.mark.parametrize("spec", all_bvh_params())
def test_position_modes_match_the_documented_meaning(spec):
    path = resolve(spec)
    record = _record(path)
    assert detect_position_modes(record) == _modes(path.name, record)
    assert read_bvh(path).skeleton.position_modes == tuple(
        _modes(path.name, record).get(n) for n in record.names)


@pytest.mark.parametrize("spec", all_bvh_params())
def test_forward_kinematics_matches_matrix_chain(spec):
    path = resolve(spec)
    record = _record(path)
    motion = read_bvh(path)
    src = motion.skeleton.source
    frames = _frames(record.num_frames)
    world, ends = reference_fk(record, _modes(path.name, record), frames)

    pose = forward_kinematics(motion.frames(frames))
    ref_joints = src.points_to_internal(world[..., :3, 3]).transpose(1, 0, 2)   # (F, J, 3)
    ref_ends = src.points_to_internal(ends).transpose(1, 0, 2)                  # (F, E, 3)
    tol = 1e-9 * stature(motion)
    assert pose.positions.shape == ref_joints.shape
    assert pose.end_positions.shape == ref_ends.shape and ref_ends.shape[1] > 0
    assert np.abs(pose.positions - ref_joints).max() <= tol
    assert np.abs(pose.end_positions - ref_ends).max() <= tol
    # world rotations: internal = C @ file (C takes the file's axes onto +Y up)
    C = src.rotation
    ref_rot = np.einsum("ab,jfbc->fjac", C, world[..., :3, :3])
    got = Rotation.from_quat(pose.rotations.reshape(-1, 4)).as_matrix().reshape(ref_rot.shape)
    assert np.abs(got - ref_rot).max() <= 1e-9


def test_reference_is_sensitive_to_the_position_mode():
    """The CC3 hip-rooted clip puts the body ~1 m under the floor if its root position channels
    are read as replacing the OFFSET: the comparison above can tell the two readings apart."""
    from conftest import shared_path
    path = shared_path("cc3_cmu_02_06_pickup.bvh")
    record = _record(path)
    frames = np.array([0])
    rel, _ = reference_fk(record, {"CC_Base_Hip": "relative"}, frames)
    ab, _ = reference_fk(record, {"CC_Base_Hip": "absolute"}, frames)
    gap = rel[0, 0, :3, 3] - ab[0, 0, :3, 3]
    np.testing.assert_allclose(gap, record.offsets[0], atol=1e-12)
    assert gap[1] > 100.0                                       # centimetres


@pytest.mark.parametrize("spec", all_bvh_params()[:3])
def test_fk_arrays_accepts_full_translations(spec):
    """fk_arrays takes (F, K, 3) translations of the animated joints or (F, J, 3) of all."""
    motion = read_bvh(resolve(spec))
    m = motion.frames(slice(0, 50))
    a = fk_arrays(m.skeleton, m.rotations, m.translations)
    b = fk_arrays(m.skeleton, m.rotations, m.local_translations())
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.end_positions, b.end_positions)
    c = fk_arrays(m.skeleton, m.rotations, m.translations, end_sites=False)
    assert c.end_positions.shape == (m.num_frames, 0, 3)
    np.testing.assert_array_equal(c.positions, a.positions)
