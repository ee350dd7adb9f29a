"""Heel-off (issue 14 point 1): within a flat plant the heel rises about the held toe before
toe-off. The detector tells it apart from a heel still down, and the correction turns the
target's foot about its held toe there instead of holding it flat, heel on the floor, while
the performer's heel rises."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import all_bvh_params, resolve
from test_foot_contacts import _auto_scene
from motion_composer.engine.correction import contacts as contacts_module
from motion_composer.engine.correction.contacts import (HEEL_OFF, HEEL_RISE, detect_contacts,
                                                        find_feet)
from motion_composer.engine.describe import figure_size
from motion_composer.engine.formats import read_performer
from motion_composer.engine.kinematics import fk_arrays

WALKS = ["cmu_max_131_01_walk.bvh", "bandai1_walk_normal_001.bvh", "cc3_cmu_02_01_walk.bvh"]


def _positions(motion, joints) -> dict:
    pos = fk_arrays(motion.skeleton, motion.rotations, motion.translations,
                    end_sites=False).positions
    return {j: pos[:, motion.skeleton.index[j]] for j in joints}


@pytest.mark.parametrize("spec", all_bvh_params())
def test_a_heel_off_is_the_heel_rising_while_the_toe_is_held(spec):
    """On every clip: after each heel-off the heel rises on every frame to its run's end, by
    half a percent of the figure or more in all, and the toe is held on each of those
    frames; before it the heel is down (the frame of heel-off no higher than any frame
    after)."""
    motion = read_performer(resolve(spec))
    feet = find_feet(motion.skeleton)
    found = detect_contacts(motion)
    if not found:
        pytest.skip("no contacts on this clip")
    size = figure_size(motion)
    pos = _positions(motion, [a for a, _ in feet])
    for c in found:
        y = pos[c.joint][:, 1]
        assert len(c.heel_down()) == len(c.heel)
        for (s, e), off in zip(c.heel, c.heel_down()):
            assert s <= off <= e
            if off == e:
                continue
            rise = np.diff(y[off:e + 1])
            assert np.all(rise > HEEL_RISE * size / motion.fps), (c, off)
            assert y[e] - y[off] >= HEEL_OFF * size
            assert all(any(bs <= f <= be for bs, be in c.ball) for f in range(off + 1, e + 1))


@pytest.mark.parametrize("clip", WALKS)
def test_a_walk_lifts_its_heels_before_toe_off(clip):
    """Walks of three conventions: the steps' plants end in a heel-off (the foot rolls onto
    its toe), each a few frames long (under a quarter second). Not every plant: the CMU walk
    turns and stops, and its heel strikes, stands and the clip's last plants have none (7 of
    its 15 plants with a heel and a toe run)."""
    from conftest import shared_path
    motion = read_performer(shared_path(clip))
    found = [c for c in detect_contacts(motion) if c.heel and c.ball]
    offs = [(e - off) for c in found for (_, e), off in zip(c.heel, c.heel_down()) if off < e]
    assert len(offs) >= max(4, len(found) / 3), (len(offs), len(found))
    assert max(offs) <= 0.25 * motion.fps


def _heel_pivots(scene, solution):
    """Per heel pin turned into a pivot (a path of points): the constraint, the frame of its
    heel-off (where its path leaves its first point) and the corrected heel and toe
    positions."""
    motion = solution.motion
    sk = motion.skeleton
    pos = fk_arrays(sk, motion.rotations, motion.translations, end_sites=False).positions
    out = []
    for c in solution.constraints:
        if c.kind != "trajectory" or (c.meta or {}).get("part") != "heel":
            continue
        path = np.asarray(c.goal["points"])
        moved = np.flatnonzero(np.any(path != path[0], axis=1))
        out.append((c, c.start + int(moved[0]) - 1, pos[:, sk.index[c.joint]]))
    return out


def test_a_heel_off_turns_the_foot_about_the_held_toe(monkeypatch):
    """The Bandai walk onto the Mixamo mannequin: at each heel-off the corrected heel leaves
    the floor and rises, at the run's end, by at least half what the performer's rises
    (both as fractions of their figures), while the toe stays where it planted (the toe's
    drift tests of tests/test_foot_contacts.py hold it). Held flat to the run's end, as
    before heel-off was told apart, the heel stays on the floor there."""
    scene = _auto_scene("bandai1_walk_normal_001.bvh", "target_mixamo_mannequin.glb")
    solution = scene.solve(regenerate=True)
    pivots = _heel_pivots(scene, solution)
    assert len(pivots) >= 5
    performer = scene.performer
    p_size, t_size = figure_size(performer), figure_size(scene.composed)
    p_pos = _positions(performer, [a for a, _ in find_feet(performer.skeleton)])
    sk = solution.motion.skeleton
    rises = []
    for c, off, heel in pivots:
        p_heel = p_pos[c.meta["performer_joint"]]
        theirs = (p_heel[c.end, 1] - p_heel[off, 1]) / p_size
        mine = (heel[c.end, 1] - heel[off, 1]) / t_size
        assert theirs > 0
        rises.append(mine / theirs)
        # the toe held over the same frames
        toes = [d for d in solution.constraints if d.meta and d.meta.get("part") == "toe"
                and d.start <= off and d.end >= c.end
                and sk.parents[sk.index[d.joint]] == sk.index[c.joint]]
        assert toes, c.name
    assert min(rises) >= 0.5, rises
    # the report measures a pivoting heel's drift up to heel-off, where it is held in place
    report = [r for r in solution.report["contacts"] if r["part"] == "heel"]
    assert report and max(r["drift_corrected_m"] for r in report) < 1e-3 * t_size
    assert solution.report["contact_drift"]["corrected_max_m"] < 1e-3 * t_size
    quality = [r for r in solution.report["quality"]["contacts"] if r["part"] == "heel"]
    assert quality and max(r["drift_corrected_m"] for r in quality) < 1e-3 * t_size

    monkeypatch.setattr(contacts_module, "HEEL_OFF", np.inf)      # no heel-off: held flat
    flat = scene.solve(regenerate=True)
    assert not _heel_pivots(scene, flat)
    sk = flat.motion.skeleton
    pos = fk_arrays(sk, flat.motion.rotations, flat.motion.translations,
                    end_sites=False).positions
    for c, off, _ in pivots:
        heel = pos[:, sk.index[c.joint]]
        assert abs(heel[c.end, 1] - heel[off, 1]) < 0.001 * t_size
