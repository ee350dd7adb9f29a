"""Self-retarget is exact (issue 14, point 4), and branching joints turn as the performer's.

A clip onto its own skeleton gives every joint's world rotation back (within 0.01 degree), and
not by recognising the skeleton: the same holds onto a copy of it with every joint renamed,
scaled by 1.3 and with its own rest rotations (each joint's local axes turned by a random
rotation, the clip re-expressed in them so that it shows the same motion). Across skeletons, a
branching joint (hips, chest, a hand with fingers and thumb) whose virtual bones on the
performer side are single bones turns exactly as the performer joint does, twist included.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from motion_composer.engine import forward_kinematics, read_bvh
from motion_composer.engine.conversion import (BindOptions, Correspondence, automap, bind,
                                               convert, retarget)
from motion_composer.engine.motion import Motion
from motion_composer.engine.quaternions import qconj, qmul, qrot
from motion_composer.engine.rotations import angle_between
from conftest import all_bvh_params, resolve, shared_path


def _deg(qa, qb):
    return np.degrees(angle_between(qa, qb))


def variant(motion: Motion, scale: float = 1.3, seed: int = 0):
    """The same motion on a copy of its skeleton: joints renamed, lengths times ``scale`` and
    every non-root joint's local axes turned by a random rotation ``R[j]`` (its world rotation
    becomes ``world[j] * R[j]``). Returns the motion and ``R`` ``(J, 4)``."""
    s = motion.skeleton
    rng = np.random.default_rng(seed)
    R = rng.normal(size=(s.num_joints, 4))
    R /= np.linalg.norm(R, axis=1, keepdims=True)
    R[0] = (0.0, 0.0, 0.0, 1.0)
    parent_R = np.array([R[p] if p >= 0 else (0.0, 0.0, 0.0, 1.0) for p in s.parents])
    sites = tuple(dataclasses.replace(e, offset=qrot(qconj(R[e.parent]), e.offset) * scale)
                  for e in s.end_sites)
    skeleton = dataclasses.replace(
        s, names=tuple(f"j{k}_{n[::-1]}" for k, n in enumerate(s.names)),
        offsets=qrot(qconj(parent_R), s.offsets) * scale, end_sites=sites)
    rotations = qmul(qmul(qconj(parent_R)[None], motion.rotations), R[None])
    translations = qrot(qconj(parent_R[s.translated])[None], motion.translations) * scale
    return Motion(skeleton, rotations, translations, motion.frame_time, "variant"), R


@pytest.mark.parametrize("spec", all_bvh_params())
def test_self_retarget_onto_a_renamed_scaled_re_rested_copy_is_exact(spec):
    motion = read_bvh(resolve(spec))
    copy, R = variant(motion)
    # the variant's rest pose is a different posture (its axes turned), so both sides take
    # their first frame as the reference pose: the same posture, other joint frames
    options = BindOptions(performer_reference=0, target_reference=0)
    corr = Correspondence(dict(zip(copy.skeleton.names, motion.skeleton.names)))
    out = retarget(motion, copy, corr, bind_options=options)
    a, b = forward_kinematics(motion), forward_kinematics(out)
    err = _deg(a.rotations, qmul(b.rotations, qconj(R)[None])).max(axis=0)
    worst = int(np.argmax(err))
    assert err[worst] < 0.01, f"{motion.skeleton.names[worst]}: {err[worst]:.4f} deg"


PAIRS = [("cc3_cmu_02_01_walk.bvh", "rokoko_mixamo_jesse_dance.bvh"),
         ("rokoko_mixamo_jesse_dance.bvh", "cc3_cmu_02_01_walk.bvh"),
         ("rokoko_mixamo_jesse_dance.bvh", "bandai1_walk_normal_001.bvh"),
         ("fair1_child5_wave_hello.bvh", "rokoko_mixamo_jesse_dance.bvh"),
         ("bandai1_walk_normal_001.bvh", "fair1_child5_wave_hello.bvh")]


@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: f"{p[0][:6]}->{p[1][:6]}")
def test_branching_joints_with_single_performer_bones_turn_as_the_performer(pair):
    performer = read_bvh(shared_path(pair[0]))
    target = read_bvh(shared_path(pair[1]))
    ps, ts = performer.skeleton, target.skeleton
    binding = bind(performer, target, automap(ts, ps))
    pose = convert(binding, performer)
    pq = forward_kinematics(performer).rotations
    checked = {}
    for j, bones in binding.bones.items():
        p = binding.mapped[j]
        if not bones.roll_by_bones or any(ps.parents[q] != p for q in bones.performer):
            continue
        turn_t = qmul(pose.world[:, j], qconj(binding.rest_world[j]))
        turn_p = qmul(pq[:, p], qconj(binding.performer_rest_world[p]))
        checked[ts.names[j]] = float(_deg(turn_t, turn_p).max())
    assert len(checked) >= 2                     # at least the hips and the chest
    worst = max(checked, key=checked.get)
    assert checked[worst] < 1.0, f"{worst}: {checked[worst]:.2f} deg"


def test_a_hand_above_metacarpals_keeps_its_twist():
    """Rokoko's fingers hang from unmapped metacarpals, CC3's straight from the hand: the
    hand's turn is not spread down the metacarpal of its primary finger (which twisted the
    hand by up to 16 degrees and moved the thumb), so the hand turns as CC3's does."""
    performer = read_bvh(shared_path("cc3_cmu_02_01_walk.bvh"))
    target = read_bvh(shared_path("rokoko_mixamo_jesse_dance.bvh"))
    binding = bind(performer, target, automap(target.skeleton, performer.skeleton))
    pose = convert(binding, performer)
    pq = forward_kinematics(performer).rotations
    for side in ("Left", "Right"):
        j = target.skeleton.index[f"{side}Hand"]
        p = binding.mapped[j]
        assert len(binding.bones[j].children) == 5 and not binding.chains.get(j)
        turn_t = qmul(pose.world[:, j], qconj(binding.rest_world[j]))
        turn_p = qmul(pq[:, p], qconj(binding.performer_rest_world[p]))
        assert _deg(turn_t, turn_p).max() < 0.01
