"""BVH round trips: read -> write (engine.formats.bvh.format_bvh / write_bvh) -> read gives the
same file.

Checked for every BVH we have (bundled clips always, ../shared/data when present): hierarchy,
channel layout, End Sites, frame time (exactly), units / up axis / position modes as detected
again from the written file, local values, and the written channel values themselves against the
original file's. Then atomic writing, and writing in another unit / up axis / position mode.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import motion_composer.engine.fileio
from conftest import all_bvh_params, resolve
from motion_composer.engine.formats.bvh import (BVHRecord, format_bvh, parse_bvh_text, read_bvh, record_to_motion,
                                write_bvh)
from motion_composer.engine.errors import ExportError
from motion_composer.engine.kinematics import forward_kinematics
from motion_composer.engine.motion import Motion
from motion_composer.engine.skeleton import Skeleton
from motion_composer.engine.units import SourceFrame

#: lengths: written with 6 decimals, so a value moves by at most 5e-7 file units
POS_TOL = 1e-6
#: rotations: largest entry of the difference of the two rotation matrices
ROT_TOL = 1e-6
#: written Euler angles against the file's, degrees (6 decimals: at most 5e-7 off)
ANGLE_TOL = 1e-6
#: an Euler triple whose middle angle is this close (degrees) to gimbal lock, or outside the
#: range a decomposition returns, has other equally valid triples: compare the rotation instead
GIMBAL_MARGIN = 0.5


def _record(path: Path) -> BVHRecord:
    return parse_bvh_text(path.read_bytes().decode("utf-8-sig"), path)


@dataclass
class RoundTrip:
    path: Path          # the original file
    record: BVHRecord   # the original file, as written
    motion: Motion      # the original file, read
    out: Path           # our output (write_bvh)
    record2: BVHRecord  # our output, as written
    motion2: Motion     # our output, read again (everything detected afresh)


@pytest.fixture(scope="module")
def roundtrip(tmp_path_factory):
    cache: dict = {}

    def get(spec) -> RoundTrip:
        if spec not in cache:
            path = resolve(spec)
            motion = read_bvh(path)
            out = tmp_path_factory.mktemp("roundtrip") / path.name
            write_bvh(motion, out)
            cache[spec] = RoundTrip(path, _record(path), motion, out, _record(out),
                                    read_bvh(out))
        return cache[spec]

    return get


def _matrices(quats: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:-1] + (3, 3))


def _columns(channels):
    """Per joint: (rotation order, rotation columns, {axis: position column})."""
    col, out = 0, []
    for chans in channels:
        order, rcols, pcols = "", [], {}
        for c in chans:
            if c.endswith("rotation"):
                order += c[0]
                rcols.append(col)
            else:
                pcols["XYZ".index(c[0])] = col
            col += 1
        out.append((order, rcols, pcols))
    return out


def _unambiguous(order: str, angles: np.ndarray) -> np.ndarray:
    """Frames whose Euler triple is the one a decomposition gives (mod 360), away from gimbal
    lock: middle angle in (-90, 90) for Tait-Bryan orders, in (0, 180) for proper Euler."""
    if len(order) < 3:
        return np.ones(len(angles), bool)
    mid = (angles[:, 1] + 180.0) % 360.0 - 180.0
    if order[0] == order[2]:
        return (mid > GIMBAL_MARGIN) & (mid < 180.0 - GIMBAL_MARGIN)
    return np.abs(mid) < 90.0 - GIMBAL_MARGIN


def _rounding_tolerance(motion: Motion, world, scale: float) -> float:
    """Largest world error [m] that writing with 6 decimals can cause: along a chain of d
    joints, every length moves by <= 5e-7 file units and every joint's rotation by <=
    sqrt(3) * 5e-7 degrees, which moves a point up to ``reach`` metres away from it."""
    d = int(motion.skeleton.depth.max()) + 2              # joints on the longest chain + site
    pts = world.all_positions()
    reach = float(np.linalg.norm(pts - pts[:, :1], axis=-1).max())
    angle = np.radians(np.sqrt(3) * 0.5e-6)
    return d * (np.sqrt(3) * 0.5e-6 * scale + angle * reach) + 1e-12


# ------------------------------------------------------------------------------------ per file
@pytest.mark.parametrize("spec", all_bvh_params())
def test_hierarchy_survives(spec, roundtrip):
    rt = roundtrip(spec)
    a, b = rt.record, rt.record2
    assert b.names == a.names
    assert b.parents == a.parents
    np.testing.assert_allclose(b.offsets, a.offsets, rtol=0, atol=POS_TOL)
    assert b.channels == a.channels
    assert rt.motion2.skeleton.rotation_orders == rt.motion.skeleton.rotation_orders
    assert [p for p, _ in b.end_sites] == [p for p, _ in a.end_sites]
    assert len(a.end_sites) == len(rt.motion.skeleton.end_sites) > 0
    for (_, off_b), (_, off_a) in zip(b.end_sites, a.end_sites):
        np.testing.assert_allclose(off_b, off_a, rtol=0, atol=POS_TOL)
    # and the same in the engine's terms (internal metres)
    sk, sk2 = rt.motion.skeleton, rt.motion2.skeleton
    scale = sk.source.scale
    np.testing.assert_allclose(sk2.offsets, sk.offsets, rtol=0, atol=POS_TOL * scale)
    for s2, s in zip(sk2.end_sites, sk.end_sites):
        assert (s2.parent, s2.name) == (s.parent, s.name)
        np.testing.assert_allclose(s2.offset, s.offset, rtol=0, atol=POS_TOL * scale)


@pytest.mark.parametrize("spec", all_bvh_params())
def test_frame_time_units_axes_and_modes_survive(spec, roundtrip):
    rt = roundtrip(spec)
    assert rt.record2.frame_time == rt.record.frame_time          # exactly, not rounded
    assert rt.motion2.frame_time == rt.motion.frame_time
    assert rt.record2.num_frames == rt.record.num_frames
    src, src2 = rt.motion.skeleton.source, rt.motion2.skeleton.source
    assert (src2.units, src2.scale, src2.up_axis) == (src.units, src.scale, src.up_axis)
    assert rt.motion2.skeleton.position_modes == rt.motion.skeleton.position_modes


@pytest.mark.parametrize("spec", all_bvh_params())
def test_values_survive(spec, roundtrip):
    rt = roundtrip(spec)
    m, m2 = rt.motion, rt.motion2
    scale = m.skeleton.source.scale
    assert m2.translations.shape == m.translations.shape
    err_t = np.abs(m2.translations - m.translations).max() / scale          # file units
    assert err_t <= POS_TOL
    err_r = np.abs(_matrices(m2.rotations) - _matrices(m.rotations)).max()
    assert err_r <= ROT_TOL
    # quaternions up to sign, the same thing said another way
    dot = np.abs(np.sum(m2.rotations * m.rotations, axis=-1))
    assert (1.0 - dot).max() <= ROT_TOL ** 2


@pytest.mark.parametrize("spec", all_bvh_params())
def test_written_channel_values_equal_the_files(spec, roundtrip):
    """The channel values we write are the file's own: positions within 1e-6, angles equal
    modulo 360 degrees where the file's Euler triple is the canonical one; elsewhere (gimbal
    lock, middle angle beyond +-90) the written angles must give the same rotation."""
    rt = roundtrip(spec)
    a, b = rt.record.values, rt.record2.values
    assert b.shape == a.shape
    compared_angles = compared_rotations = 0
    for order, rcols, pcols in _columns(rt.record.channels):
        for col in pcols.values():
            assert np.abs(b[:, col] - a[:, col]).max() <= POS_TOL
        if not rcols:
            continue
        ang_a, ang_b = a[:, rcols], b[:, rcols]
        plain = _unambiguous(order, ang_a)
        diff = (ang_b[plain] - ang_a[plain] + 180.0) % 360.0 - 180.0
        assert diff.size == 0 or np.abs(diff).max() <= ANGLE_TOL, (order, np.abs(diff).max())
        compared_angles += int(plain.sum())
        if not plain.all():
            Ra = Rotation.from_euler(order, ang_a[~plain], degrees=True).as_matrix()
            Rb = Rotation.from_euler(order, ang_b[~plain], degrees=True).as_matrix()
            assert np.abs(Ra - Rb).max() <= ROT_TOL
            compared_rotations += int((~plain).sum())
    assert compared_angles > 0
    # every joint-frame was checked one way or the other
    n_rot = sum(1 for o, _, _ in _columns(rt.record.channels) if o) * a.shape[0]
    assert compared_angles + compared_rotations == n_rot


@pytest.mark.parametrize("spec", all_bvh_params())
@pytest.mark.parametrize("target", [SourceFrame(units="m", scale=1.0, up_axis="+Y"),
                                    SourceFrame(units="mm", scale=0.001, up_axis="+Z")],
                         ids=["m+Y", "mm+Z"])
def test_other_units_and_axes_give_the_same_world(spec, target, tmp_path, roundtrip):
    """Written in metres +Y (or mm +Z), read back with those units given: same world."""
    motion = roundtrip(spec).motion
    out = tmp_path / "other.bvh"
    write_bvh(motion, out, source=target)
    again = read_bvh(out, units=target.units, up_axis=target.up_axis)
    assert again.skeleton.source.up_axis == target.up_axis
    assert again.skeleton.source.scale == target.scale
    # the file really is in the new frame: root offset and first row follow the conversion
    rec = _record(out)
    np.testing.assert_allclose(
        target.points_to_internal(rec.offsets[0]),
        motion.skeleton.offsets[0], rtol=0, atol=1e-6 * target.scale)
    p0 = forward_kinematics(motion)
    p1 = forward_kinematics(again)
    tol = _rounding_tolerance(motion, p0, target.scale)
    assert np.abs(p1.positions - p0.positions).max() <= tol
    assert np.abs(p1.end_positions - p0.end_positions).max() <= tol
    assert np.abs(_matrices(p1.rotations) - _matrices(p0.rotations)).max() <= ROT_TOL


@pytest.mark.parametrize("spec", all_bvh_params())
def test_other_position_modes_give_the_same_world(spec, roundtrip):
    """Position channels written with the opposite meaning (relative <-> absolute) and read back
    with that meaning given: the same world. Joints with a zero OFFSET write the same values
    either way; the others must change their values by exactly the OFFSET."""
    motion = roundtrip(spec).motion
    sk = motion.skeleton
    flipped = {sk.names[j]: ("absolute" if m == "relative" else "relative")
               for j, m in enumerate(sk.position_modes) if m}
    text = format_bvh(motion, position_modes=flipped)
    rec = parse_bvh_text(text)
    orig = roundtrip(spec).record
    cols = _columns(orig.channels)
    for name, mode in flipped.items():
        j = sk.joint(name)
        sign = 1.0 if mode == "absolute" else -1.0         # absolute = relative + OFFSET
        for axis, col in cols[j][2].items():
            np.testing.assert_allclose(rec.values[:, col],
                                       orig.values[:, col] + sign * orig.offsets[j][axis],
                                       rtol=0, atol=POS_TOL)
    back = record_to_motion(rec, units=sk.source.units, up_axis=sk.source.up_axis,
                            position_mode=flipped)
    w0 = forward_kinematics(motion)
    p0, p1 = w0.all_positions(), forward_kinematics(back).all_positions()
    assert np.abs(p1 - p0).max() <= _rounding_tolerance(motion, w0, sk.source.scale)


# ------------------------------------------------------------------------------ atomic writes
def _tiny_motion(rotate_leaf: bool) -> Motion:
    """Two joints; the leaf has no rotation channels, so rotating it cannot be written."""
    sk = Skeleton(names=["root", "leaf"], parents=[-1, 0], offsets=[[0, 1, 0], [0, 0.5, 0]],
                  channels=[("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                             "Yrotation"), ()],
                  source=SourceFrame(units="cm", scale=0.01, up_axis="+Y"))
    rot = np.zeros((3, 2, 4))
    rot[..., 3] = 1.0
    rot[:, 0] = Rotation.from_euler("ZXY", [[10, 20, 30], [0, 0, 5], [-40, 1, 2]],
                                    degrees=True).as_quat()
    if rotate_leaf:
        rot[1, 1] = Rotation.from_euler("X", 30, degrees=True).as_quat()
    trans = np.array([[[0, 1, 0]], [[0.1, 1, 0]], [[0.2, 1.1, 0.3]]])
    return Motion(sk, rot, trans, frame_time=1 / 30)


def test_write_replaces_an_existing_file_wholly(tmp_path):
    out = tmp_path / "clip.bvh"
    out.write_text("OLD CONTENT\n" * 100_000)                 # longer than the new file
    motion = _tiny_motion(rotate_leaf=False)
    write_bvh(motion, out)
    assert out.read_text() == format_bvh(motion)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh"]   # no temp file left
    again = read_bvh(out, units="cm", up_axis="+Y")
    assert np.abs(again.translations - motion.translations).max() <= 1e-8


def test_write_goes_through_a_temporary_file_and_rename(tmp_path, monkeypatch):
    out = tmp_path / "clip.bvh"
    out.write_text("OLD\n")
    seen = []
    real_replace = os.replace

    def spy(src, dst):
        seen.append((Path(src), Path(dst), Path(src).read_text(), out.read_text()))
        return real_replace(src, dst)

    monkeypatch.setattr(motion_composer.engine.fileio.os, "replace", spy)
    motion = _tiny_motion(rotate_leaf=False)
    write_bvh(motion, out)
    assert len(seen) == 1
    src, dst, src_text, target_text_meanwhile = seen[0]
    assert dst == out and src.parent == out.parent and src != out
    assert src_text == format_bvh(motion)          # complete before the rename
    assert target_text_meanwhile == "OLD\n"        # the old file untouched until the rename
    assert not src.exists()


def test_failed_format_leaves_the_old_file_intact(tmp_path):
    out = tmp_path / "clip.bvh"
    old = b"HIERARCHY\nthe user's previous save\n"
    out.write_bytes(old)
    with pytest.raises(ExportError, match="leaf"):
        write_bvh(_tiny_motion(rotate_leaf=True), out)
    assert out.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh"]


def test_failed_rename_leaves_the_old_file_intact(tmp_path, monkeypatch):
    out = tmp_path / "clip.bvh"
    old = b"the user's previous save\n"
    out.write_bytes(old)

    def broken(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(motion_composer.engine.fileio.os, "replace", broken)
    with pytest.raises(motion_composer.engine.fileio.FileWriteError, match="No space left on device"):
        write_bvh(_tiny_motion(rotate_leaf=False), out)
    assert out.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh"]


# ------------------------------------------------------------------ joints with 1 or 2 axes
def _few_axes_motion(euler_2: np.ndarray, euler_1: np.ndarray) -> Motion:
    sk = Skeleton(names=["root", "two", "one"], parents=[-1, 0, 1],
                  offsets=[[0, 0, 0], [0, 1, 0], [0.5, 0, 0]],
                  channels=[("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                             "Yrotation"), ("Xrotation", "Yrotation"), ("Zrotation",)],
                  source=SourceFrame(units="m", scale=1.0, up_axis="+Y"))
    F = len(euler_2)
    rot = np.zeros((F, 3, 4))
    rot[..., 3] = 1.0
    rot[:, 1] = Rotation.from_euler("XY", euler_2, degrees=True).as_quat()
    rot[:, 2] = Rotation.from_euler("Z", euler_1[:, None], degrees=True).as_quat()
    return Motion(sk, rot, np.zeros((F, 1, 3)), frame_time=0.01)


def test_one_and_two_axis_joints_round_trip_at_any_angle():
    """A joint with channels 'Xrotation Yrotation' turned by Ry beyond +-90 degrees is a
    rotation its two channels can hold; writing must find those two angles (it once took the
    decomposition with |Y| <= 90, whose dropped Z angle is 180, and refused the motion)."""
    rng = np.random.default_rng(7)
    euler_2 = rng.uniform(-179, 179, size=(200, 2))
    euler_2[:4] = [[30, 120], [-10, -170], [170, 95], [0, 91]]
    euler_1 = rng.uniform(-179, 179, size=200)
    motion = _few_axes_motion(euler_2, euler_1)
    text = format_bvh(motion)
    rec = parse_bvh_text(text)
    assert rec.channels[1] == ("Xrotation", "Yrotation") and rec.channels[2] == ("Zrotation",)
    written_2, written_1 = rec.values[:, 6:8], rec.values[:, 8]
    # channel values equal the angles the motion was made from, modulo 360
    for got, want in ((written_2, euler_2), (written_1, euler_1)):
        assert np.abs((got - want + 180.0) % 360.0 - 180.0).max() <= ANGLE_TOL
    back = record_to_motion(rec, units="m", up_axis="+Y")
    assert np.abs(_matrices(back.rotations) - _matrices(motion.rotations)).max() <= ROT_TOL


def test_two_axis_joint_refuses_a_rotation_about_its_missing_axis():
    motion = _few_axes_motion(np.array([[10.0, 20.0]]), np.array([5.0]))
    rot = np.array(motion.rotations)
    rot[0, 1] = Rotation.from_euler("XYZ", [10, 20, 30], degrees=True).as_quat()
    with pytest.raises(ExportError, match="'two'"):
        format_bvh(motion.replace(rotations=rot))


@pytest.mark.parametrize("spec", [("bundled", "cmu_131_01_walk.bvh"),
                                  ("shared", "bandai1_walk_normal_001.bvh")],
                         ids=lambda s: s[1])
def test_a_root_that_starts_far_from_its_offset_reads_back_where_it_was(spec):
    """A root with an OFFSET of its own (the robot's ``Bone`` stands 19.5 cm behind the
    origin) whose first frame is elsewhere (the figure turned to face as the performer):
    written as it was, its absolute position channels looked like values added to the
    OFFSET (nearer zero than the OFFSET on its long axis), and the output read back 0.195 m
    off on every joint. The root is written with its first frame's position as its OFFSET,
    as the other joints that moved from theirs already were."""
    import dataclasses
    motion = read_bvh(resolve(spec))
    sk = motion.skeleton
    offsets = sk.offsets.copy()
    offsets[0] = [0.0, 0.0, -0.195]
    tra = motion.translations.copy()
    tra[:, 0, 2] += 0.3 - tra[0, 0, 2]                          # frame 0 at z = +0.3
    moved = Motion(dataclasses.replace(sk, offsets=offsets), motion.rotations, tra,
                   motion.frame_time, motion.name)
    back = parse_bvh_text(format_bvh(moved))
    back = record_to_motion(back, units=sk.source.units, up_axis=sk.source.up_axis)
    w0 = forward_kinematics(moved)
    p0, p1 = w0.all_positions(), forward_kinematics(back).all_positions()
    assert np.abs(p1 - p0).max() <= _rounding_tolerance(moved, w0, sk.source.scale)
