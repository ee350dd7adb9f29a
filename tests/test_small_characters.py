"""A character smaller than the solvers' full size (:data:`engine.correction.ik.FULL_SIZE`,
1 m) is corrected as the same character scaled up to it: its automatic contacts, its dense
correction and its fitted keys do not depend on its size. A file written in the wrong unit
(Blender's FBX exporter at a scale of 0.01 gives a figure 2 cm tall) states that size, so the
engine must cope with it: before, the contact detector and the solve clamped the stature at
0.1 m and the tolerances were absolute (0.1 mm, half a percent of such a figure), and the CMU
walk onto Bandai at 1/64 of its size found 4 contacts instead of 8 and ended 25 degrees away.

The scales are powers of two, so that the scaled files are the same numbers to the bit and
what differs is the engine's own lengths."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ik_fixtures import walk_on_bandai
from motion_composer.engine import forward_kinematics
from motion_composer.engine.conversion import retarget
from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.ik import FULL_SIZE, IKOptions, length_share
from motion_composer.engine.correction.keyfit import TASK_LIMIT, fit_to_tasks, solved_keys
from motion_composer.engine.describe import figure_size, stature
from motion_composer.engine.quaternions import qconj, qmul
from motion_composer.engine.skeleton import EndSite

#: the first seconds of the CMU walk (120 fps): eight contacts on the way
FRAMES = 400


def _scaled(motion, k):
    sk = motion.skeleton
    skeleton = dataclasses.replace(sk, offsets=sk.offsets * k, end_sites=[
        EndSite(e.parent, e.offset * k, e.name) for e in sk.end_sites])
    return motion.replace(skeleton=skeleton, translations=motion.translations * k)


def _angles(a, b):
    """[deg] per frame and joint, the turn between two motions' local rotations."""
    d = qmul(a.rotations, qconj(b.rotations))
    return np.degrees(2 * np.arcsin(np.clip(np.linalg.norm(d[..., :3], axis=-1), 0, 1)))


_SOLVED = {}


def _solve(k):
    """The walk and Bandai both scaled by ``k``: the performer, the direct conversion, the
    contacts, their constraints and the dense correction."""
    if k not in _SOLVED:
        performer, target, corr, _ = walk_on_bandai()
        performer = performer.replace(rotations=performer.rotations[:FRAMES],
                                      translations=performer.translations[:FRAMES])
        p, t = _scaled(performer, k), _scaled(target, k)
        composed = retarget(p, t, corr)
        contacts = detect_contacts(p)
        cons = contact_constraints(contacts, p, composed, corr.pairs)
        _SOLVED[k] = (p, composed, contacts, cons, enforce(composed, cons))
    return _SOLVED[k]


#: half size (0.85 m, under FULL_SIZE) against 1/64 (2.7 cm)
HALF, TINY = 0.5, 1.0 / 64


def test_the_walk_at_two_small_sizes_is_under_full_size():
    for k in (HALF, TINY):
        p, composed = _solve(k)[:2]
        assert stature(composed) < FULL_SIZE
        assert figure_size(composed) == stature(composed)
    assert stature(_solve(TINY)[1]) < 0.03


def test_a_tiny_performer_gives_the_same_contacts():
    big, tiny = _solve(HALF)[2], _solve(TINY)[2]
    assert len(big) >= 8
    assert [(c.joint, c.start, c.end, c.heel, c.ball) for c in tiny] == \
        [(c.joint, c.start, c.end, c.heel, c.ball) for c in big]


def test_a_tiny_character_gets_the_same_dense_correction():
    """Within 0.01 degree and 0.01 mm at the half size (a one-sided plane's slack, 1e-7 m, is
    the one length left absolute: 0.002 degree)."""
    (_, c_big, _, cons_big, big), (_, _, _, cons_tiny, tiny) = _solve(HALF), _solve(TINY)
    assert len(cons_big) == len(cons_tiny) > 16
    assert _angles(big.motion, tiny.motion).max() < 0.01
    assert np.abs(big.root / HALF - tiny.root / TINY).max() < 1e-5
    p_big = forward_kinematics(big.motion).positions / HALF
    p_tiny = forward_kinematics(tiny.motion).positions / TINY
    assert np.abs(p_big - p_tiny).max() < 1e-5
    # the correction is real: the feet move by centimetres at the half size
    moved = forward_kinematics(c_big).positions - forward_kinematics(big.motion).positions
    assert np.abs(moved).max() / HALF > 0.01
    # and as many iterations: the tiny one converges as the other does
    assert abs(int(tiny.iterations.sum()) - int(big.iterations.sum())) <= \
        0.02 * big.iterations.sum()


def test_a_tiny_characters_keys_hold_its_tasks_as_closely():
    """The keys fitted to the tasks miss them by no more, relative to the size, than at the
    half size: within TASK_LIMIT of the character scaled to FULL_SIZE (before, the tiny
    one's limit was the absolute 1 mm, 4 % of its stature, and no key was added: its keys
    missed by 3 mm at full size), and the solve keeps them."""
    worst = {}
    for k in (HALF, TINY):
        p, composed, _, cons, dense = _solve(k)
        stats = {}
        fit_to_tasks(composed, cons, dense.rotvecs, dense.root, stats=stats)
        worst[k] = stats["worst_task_m"] * FULL_SIZE / figure_size(composed)
        assert stats["rounds"] > 0
        assert worst[k] <= TASK_LIMIT
        assert solved_keys(composed, composed, cons, dense) is not None
    assert worst[TINY] == pytest.approx(worst[HALF], rel=0.2)


def test_the_key_fits_lengths_grow_over_giant_only():
    """Continuous at GIANT; human sizes keep the fit's settings to the bit."""
    from motion_composer.engine.correction.keyfit import GIANT, fit_share
    assert fit_share(1.7) == fit_share(GIANT) == 1.0
    assert fit_share(0.25 * FULL_SIZE) == 0.25
    assert fit_share(30 * GIANT) == pytest.approx(30.0)


def test_the_solvers_lengths_shrink_below_full_size_only():
    """``length_share`` is 1 from FULL_SIZE up: human sizes keep the settings to the bit."""
    assert length_share(1.7) == length_share(FULL_SIZE) == 1.0
    assert length_share(0.25 * FULL_SIZE) == 0.25
    assert IKOptions(scale=1.7).met_below() == 1e-4
    assert IKOptions(scale=0.5 * FULL_SIZE).met_below() == pytest.approx(0.5e-4)
    assert IKOptions(scale=0.02).met_below() == pytest.approx(1e-4 * 0.02 / FULL_SIZE)


def test_a_figure_lying_flat_is_measured_by_its_length():
    """A snake lying along +X (five joints 0.3 m apart, no height): its size for the solvers
    is a tenth of its length, not its height (0); one joint alone measures 1 m. A human lying
    down is wider than a tenth of its length: its size stays its stature (the walk's first
    frame turned to lie along +Z: 0.22 m, its shoulders' width)."""
    from motion_composer.engine.motion import Motion
    from motion_composer.engine.quaternions import about_axis
    from motion_composer.engine.skeleton import Skeleton
    snake = Skeleton(names=[f"s{i}" for i in range(5)], parents=[-1, 0, 1, 2, 3],
                     offsets=[[0.0, 0.1, 0.0]] + [[0.3, 0.0, 0.0]] * 4,
                     channels=[("Xposition", "Yposition", "Zposition", "Zrotation",
                                "Xrotation", "Yrotation")] + [("Zrotation", "Xrotation",
                                                               "Yrotation")] * 4)
    still = Motion(snake, np.tile([0.0, 0.0, 0.0, 1.0], (3, 5, 1)), np.zeros((3, 1, 3)),
                   1 / 30)
    assert stature(still) == 0.0
    assert figure_size(still) == pytest.approx(0.12)
    dot = Skeleton(names=["dot"], parents=[-1], offsets=[[0.0, 0.0, 0.0]],
                   channels=[("Xposition", "Yposition", "Zposition")])
    assert figure_size(Motion(dot, np.tile([0.0, 0.0, 0.0, 1.0], (2, 1, 1)),
                              np.zeros((2, 1, 3)), 1 / 30)) == 1.0
    performer = walk_on_bandai()[0]
    one = performer.replace(rotations=performer.rotations[:1],
                            translations=performer.translations[:1])
    rot = one.rotations.copy()
    rot[:, 0] = qmul(about_axis(np.array([1.0, 0.0, 0.0]), np.pi / 2), rot[:, 0])
    lying = one.replace(rotations=rot)
    assert 0.15 < figure_size(lying) == stature(lying) < 0.5 * stature(one)
