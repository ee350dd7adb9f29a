"""The writer's Euler angles, found once for a joint that never moves and with the curves to
unwrap found on joint-major rows, against the writer as it was (scipy's ``as_euler`` of every
frame, every curve's steps looked at): the same text, character for character, on every clip
and on adversarial rotations (near gimbal lock, near half a turn, near rounding ties of the
written digits) in all six axis orders, joints still and moving."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import all_bvh_params, resolve
from motion_composer.engine.formats import bvh
from motion_composer.engine.formats.bvh import format_bvh, read_bvh, parse_bvh
from motion_composer.engine.motion import Motion
from motion_composer.engine.quaternions import from_euler
from motion_composer.engine.rotations import quat_to_euler

ORDERS = ["".join(p) for p in itertools.permutations("XYZ")]


def _scipy_angles(q, order):
    """The writer's angles as they were: scipy's for every quaternion of every frame."""
    F, G = q.shape[:2]
    flat = q.transpose(1, 0, 2).reshape(-1, 4)
    return quat_to_euler(flat, order, unwrap=False).reshape(G, F, len(order))


def _old_jumps(angles):
    """The curves the writer unwrapped, found as it found them."""
    if angles.shape[1] < 2:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    return np.nonzero(np.any(np.abs(np.diff(angles, axis=1)) >= 180.0, axis=1))


def _as_before(monkeypatch):
    monkeypatch.setattr(bvh, "_joint_angles", _scipy_angles)
    monkeypatch.setattr(bvh, "_jumps", _old_jumps)


def _adversarial(order: str, rng) -> np.ndarray:
    """Quaternions ``(n, 4)`` whose angles sit where a few ulp matter: middle angle at and
    around gimbal lock (+-90 degrees, within scipy's 1e-7 rad and just outside), outer angles
    at and around +-180, angles a hair from a tie at 6 and 3 decimals, tiny and zero angles,
    and random ones."""
    n = 4000
    angles = rng.uniform(-180, 180, size=(n, 3))
    angles[:, 1] = rng.uniform(-90, 90, size=n)
    m = n // 8
    lock = np.rad2deg(np.array([0.0, 1e-7, 0.99e-7, 1.01e-7, 1e-9, 2e-7, 1e-5]))
    angles[:m, 1] = rng.choice([-1, 1], m) * (90 - rng.choice(lock, m))
    angles[m:2 * m, 0] = rng.choice([-1, 1], m) * (180 - rng.choice([0, 1e-13, 1e-11, 1e-9], m))
    angles[2 * m:3 * m, 2] = rng.choice([-1, 1], m) * (180 - rng.choice([0, 1e-13, 1e-11], m))
    k = rng.integers(-180_000_000, 180_000_000, size=(m, 3))
    angles[3 * m:4 * m] = (k + 0.5 + rng.choice([0, 1e-7, -1e-7, 1e-5], (m, 3))) / 1e6
    k = rng.integers(-180_000, 180_000, size=(m, 3))
    angles[4 * m:5 * m] = (k + 0.5 + rng.choice([0, 1e-9, -1e-9], (m, 3))) / 1e3
    angles[5 * m:6 * m] = rng.choice([0.0, -0.0, 1e-12, 4.99e-7, 5e-7, 5.01e-7], (m, 3))
    q = from_euler(angles, order)
    q[6 * m:7 * m] = np.array([0.0, 0.0, 0.0, 1.0])
    q[7 * m:7 * m + 4] = -q[7 * m:7 * m + 4]                     # the other sign
    return q


def _texts(motion):
    out = []
    for options in ({}, {"decimals": 3}, {"decimals": 9}, {"decimals": 0},
                    {"channels": "rotation"}):
        try:
            out.append(format_bvh(motion, **options))
        except Exception as exc:                    # a moving joint cannot lose its channels
            out.append(repr(exc))
    return out


@pytest.mark.parametrize("spec", all_bvh_params())
def test_every_clip_is_written_as_before(spec, monkeypatch):
    motion = read_bvh(resolve(spec))
    now = _texts(motion)
    _as_before(monkeypatch)
    assert now == _texts(motion)


_SIX = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
""" + "".join(f"""  JOINT J{k}_{o}
  {{
    OFFSET 0 {k + 1} 0
    CHANNELS 3 {o[0]}rotation {o[1]}rotation {o[2]}rotation
    End Site
    {{
      OFFSET 0 1 0
    }}
  }}
""" for k, o in enumerate(ORDERS)) + """}
MOTION
Frames: 1
Frame Time: 0.0333333
""" + " ".join(["0"] * 24) + "\n"


def test_adversarial_rotations_are_written_as_before(monkeypatch):
    """A figure with a joint in each of the six orders, posed at the adversarial rotations
    (the root too), frame after frame: including curves that step by half a turn."""
    base = parse_bvh(_SIX, "six.bvh", units="cm", up_axis="+Y")
    sk = base.skeleton
    rng = np.random.default_rng(20261203)
    F = 4000
    rotations = np.empty((F, sk.num_joints, 4))
    for j, order in enumerate(sk.rotation_orders):
        rotations[:, j] = _adversarial(order, rng)[rng.permutation(F)]
    rotations[:, [2, 5]] = rotations[:1, [2, 5]]          # joints that never move
    motion = Motion(sk, rotations, np.tile(base.translations[:1], (F, 1, 1)), base.frame_time)
    one = Motion(sk, rotations[7:8], base.translations[:1], base.frame_time)
    now = _texts(motion) + _texts(one)
    _as_before(monkeypatch)
    assert now == _texts(motion) + _texts(one)
