"""Displacement maps: curves, interpolation, key reduction, applying to real motion."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.displacement import (ROOT, Curve, DisplacementMap,
                                                            hermite_basis, reduce_keys)
from motion_composer.engine.correction.keyfit import fit_to_tasks, key_budget
from motion_composer.engine.errors import MotionComposerError
from motion_composer.engine import forward_kinematics
from motion_composer.engine.rotations import angle_between
from ik_fixtures import walk_on_holden


def test_linear_smooth_and_constant_interpolation():
    t = np.array([0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 20.0])
    lin = Curve([0, 10, 20], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(lin.evaluate(t), [0, .25, .5, .75, 1, .75, .5, 0])
    step = Curve([0, 10, 20], [0.0, 1.0, 0.0], ("constant", "constant", "constant"))
    np.testing.assert_allclose(step.evaluate(t), [0, 0, 0, 0, 1, 1, 1, 0])
    smooth = Curve([0, 10, 20, 30], [0.0, 1.0, 3.0, 3.0], ("smooth",) * 4)
    v = smooth.evaluate(np.linspace(0, 30, 301))
    assert np.all(np.diff(v) >= -1e-12)                  # monotone keys: no overshoot
    assert v.max() <= 3.0 + 1e-12
    np.testing.assert_allclose(smooth.evaluate([0, 10, 20, 30]), [0, 1, 3, 3])
    # outside the keys the end values hold
    np.testing.assert_allclose(lin.evaluate([-5, 25]), [0, 0])


def test_curve_validation():
    with pytest.raises(MotionComposerError, match="increase"):
        Curve([0, 0], [1, 2])
    with pytest.raises(MotionComposerError, match="interpolation"):
        Curve([0, 1], [1, 2], ("linear", "bezier"))
    with pytest.raises(MotionComposerError, match="as many values"):
        Curve([0, 1, 2], [1, 2])


@pytest.mark.parametrize("tolerance", [1e-2, 1e-3, 1e-4])
def test_key_reduction_stays_within_its_tolerance_with_few_keys(tolerance):
    x = np.arange(600)
    signal = 0.2 * np.sin(x / 40.0) * np.exp(-((x - 300) / 150.0) ** 2)
    curve = reduce_keys(signal, tolerance)
    assert np.abs(curve.evaluate(x) - signal).max() <= tolerance
    assert len(curve) < 600 / 4
    linear = reduce_keys(signal, tolerance, smooth=False)
    assert np.abs(linear.evaluate(x) - signal).max() <= tolerance
    assert len(curve) <= len(linear)


def test_a_dense_ik_result_becomes_few_keys_and_applies_back():
    performer, target, corr, composed = walk_on_holden()
    hand = forward_kinematics(composed).positions[:, target.skeleton.index["LeftHand"]]
    c = Constraint("LeftHand", "position", {"point": hand[420] + [0.1, 0.2, 0.05]},
                   380, 420, 520, 570)
    result = enforce(composed, [c])
    dmap = result.displacement_map(rotation_tolerance=np.radians(0.01),
                                   position_tolerance=1e-5)
    keys = sum(len(curve) for curve in dmap.curves.values())
    dense = np.count_nonzero(result.rotvecs)                # channel-frames the IK changed
    # the corrections follow a walking arm: about half the frames stay keys at 0.01 degree
    assert 0 < keys < dense * 0.6
    applied = dmap.apply(composed)
    assert np.degrees(angle_between(applied.rotations, result.motion.rotations)).max() < 0.02
    # the map is zero before smooth_in and after smooth_out: the composed motion exactly
    np.testing.assert_array_equal(applied.rotations[:c.smooth_in],
                                  composed.rotations[:c.smooth_in])
    np.testing.assert_array_equal(applied.rotations[c.smooth_out + 1:],
                                  composed.rotations[c.smooth_out + 1:])
    # the hand still reaches within about a millimetre
    got = forward_kinematics(applied).positions[420:521, target.skeleton.index["LeftHand"]]
    assert np.linalg.norm(got - c.goal["point"], axis=1).max() < 2e-3


def test_keys_fitted_to_the_task_hold_a_reach_with_a_tenth_of_the_window_as_keys():
    """Issue 15 point 1's design (engine/correction/keyfit.py) on one reach: the keys are
    fitted to the hand's task, not to the dense curves that follow the walking arm."""
    performer, target, corr, composed = walk_on_holden()
    sk = target.skeleton
    hand = forward_kinematics(composed).positions[:, sk.index["LeftHand"]]
    c = Constraint("LeftHand", "position", {"point": hand[420] + [0.1, 0.2, 0.05]},
                   380, 420, 520, 570)
    result = enforce(composed, [c])
    stats = {}
    dmap = fit_to_tasks(composed, [c], result.rotvecs, result.root, stats=stats)
    window = c.smooth_out - c.smooth_in + 1
    assert dmap.curves and all(len(curve) <= key_budget(composed.fps) * window
                               for curve in dmap.curves.values())
    applied = dmap.apply(composed)
    got = forward_kinematics(applied).positions[c.start:c.end + 1, sk.index["LeftHand"]]
    assert np.linalg.norm(got - c.goal["point"], axis=1).max() < 1e-3
    assert stats["worst_task_m"] < 1e-3
    # zero outside the window: the composed motion bit for bit
    outside = np.r_[0:c.smooth_in, c.smooth_out + 1:composed.num_frames]
    np.testing.assert_array_equal(applied.rotations[outside], composed.rotations[outside])
    np.testing.assert_array_equal(applied.translations[outside],
                                  composed.translations[outside])
    # between two keys a curve is the Hermite cubic of their values and out / in slopes
    curve = max(dmap.curves.values(), key=len)
    m = curve.tangent_slopes()
    k = len(curve) // 2
    f0, f1 = curve.frames[k], curve.frames[k + 1]
    u = np.linspace(0, 1, 5)
    b0, b1, b2, b3 = hermite_basis(u)
    h = f1 - f0
    np.testing.assert_allclose(curve.evaluate(f0 + u * h),
                               b0 * curve.values[k] + b1 * h * m[k, 1]
                               + b2 * curve.values[k + 1] + b3 * h * m[k + 1, 0], atol=1e-15)


def test_offsets_add_to_the_composed_motion_which_never_changes():
    performer, target, corr, composed = walk_on_holden()
    before = composed.rotations.copy()
    dmap = DisplacementMap({("LeftForeArm", "rx"): Curve([0, 100, 200], [0.0, 0.5, 0.0]),
                            (ROOT, "ty"): Curve([0, 200], [0.0, 0.1])})
    out = dmap.apply(composed)
    np.testing.assert_array_equal(composed.rotations, before)
    j = target.skeleton.index["LeftForeArm"]
    turn = angle_between(out.rotations[100, j], composed.rotations[100, j])
    assert turn == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(out.translations[:, 0, 1] - composed.translations[:, 0, 1],
                               np.clip(np.arange(composed.num_frames) / 200 * 0.1, 0, 0.1),
                               atol=1e-12)
    others = [k for k in range(target.skeleton.num_joints) if k != j]
    np.testing.assert_array_equal(out.rotations[:, others], composed.rotations[:, others])


def test_maps_round_trip_through_plain_data_and_reject_unknown_channels():
    dmap = DisplacementMap({("Hips", "rz"): Curve([0, 5.5], [0.1, -0.2], ("smooth", "linear")),
                            (ROOT, "tx"): Curve([3], [0.25])})
    back = DisplacementMap.from_dict(dmap.to_dict())
    assert back.to_dict() == dmap.to_dict()
    with pytest.raises(MotionComposerError, match="root channels"):
        DisplacementMap({(ROOT, "rx"): Curve([0], [0])})
    with pytest.raises(MotionComposerError, match="joint channels"):
        DisplacementMap({("Hips", "tx"): Curve([0], [0])})


def test_a_fit_round_splits_each_missing_interval_at_its_worst_frame():
    """Per key interval with frames over the tolerance, the worst frame becomes a key; when
    that frame is a key already, the middles of the intervals beside it do (those at least two
    frames wide)."""
    from motion_composer.engine.correction.displacement import _splits
    keys = np.array([0, 10, 20, 21, 30])
    frames = np.array([3, 7, 10, 12, 21, 25, 30])
    err = np.array([1.0, 2.0, 5.0, 1.0, 3.0, 1.0, 4.0])
    # [0, 10): 7; [10, 20): 10 is a key -> 5 and 15; [20, 21): none over; [21, 30): 21 is a
    # key -> 25 (the interval before it, 20..21, is too narrow); [30]: a key -> 25
    assert _splits(keys, frames, err).tolist() == [5, 7, 15, 25]
