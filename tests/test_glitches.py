"""One-frame glitches of a capture under held goals (engine/correction/glitches.py).

An optical capture that throws the whole body out and back for one frame while a foot is
planted (the CMU jumps at 975 and 980) is solved there from the way between the frames
around it: the planted foot stays and no joint pops, where solved from the glitched posture
the standing legs took the glitch and turned up to twice the no-pop limit. Checked by
writing such a glitch into clean captures (the FAIR child's jump, the Xia run: a turn of the
body of 4.5 degrees and 5 mm for one frame, inside a ramp where the other foot is held): the
glitch is found, the corrected motion has the clean capture's pops and nothing of the glitch,
the rest is the clean solve's; and by looking for glitches in every shared capture: only the
CMU jumps have them.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import BUNDLED_BVH, SHARED_BVH, clip_path, shared_path
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.glitches import held_glitches, without_glitches
from motion_composer.engine.correction.quality import quality
from motion_composer.engine.describe import figure_size
from motion_composer.engine.formats import read_motion
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.motion import Motion
from motion_composer.engine.project import Project, Source
from motion_composer.engine.quaternions import about_axis, qmul
from motion_composer.engine.rotations import angle_between
from motion_composer.engine.scene import Scene

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _scene(performer, performer_file, target_file) -> Scene:
    target = read_motion(target_file)
    project = Project(performer=Source(str(performer_file)), target=Source(str(target_file)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    return Scene(project, performer, target)


def _glitched(performer: Motion, frames) -> Motion:
    """``performer`` with its body thrown for one frame at each of ``frames``: turned 4.5
    degrees about its left-right axis and moved 5 mm forward, and back on the next frame."""
    sk = performer.skeleton
    top = sk.body_top()
    rot = performer.rotations.copy()
    tra = performer.translations.copy()
    for f in frames:
        rot[f, top] = qmul(about_axis(np.array([1.0, 0.0, 0.0]), np.radians(4.5)),
                           rot[f, top])
        tra[f, 0] += [0.0, 0.0, 0.005]
    return Motion(sk, rot, tra, performer.frame_time, performer.name)


def _positions(motion) -> np.ndarray:
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations,
                     end_sites=False).positions


def _worst_pop(performer, composed, correction, constraints):
    q = quality(performer, composed, correction.motion, constraints, correction.residual)
    return q["pops"][0]


#: (clip, target, frames the glitch is written at: inside a ramp, the other foot held)
CASES = {
    "jump-fair1-tpose": (("bundled", "fair1_child8_jumping.bvh"),
                         ("bundled", "cmu_rest_tpose.bvh"), (391, 409)),
    "run-xia-ely": (("shared", "cmu_xia_angry_13_000_run.bvh"),
                    ("shared", "target_mixamo_ely.glb"), (48,)),
}


def _path(where: str, name: str):
    return clip_path(name) if where == "bundled" else shared_path(name)


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_a_glitch_under_a_planted_foot_is_solved_from_the_frames_around_it(case):
    (pw, pn), (tw, tn), frames = CASES[case]
    performer_file, target_file = _path(pw, pn), _path(tw, tn)
    performer = read_motion(performer_file)
    clean = _scene(performer, performer_file, target_file)
    thrown = _scene(_glitched(performer, frames), performer_file, target_file)
    cons = clean.automatic_constraints()
    assert [c.range for c in thrown.automatic_constraints()] == [c.range for c in cons]
    for f in frames:                  # the glitch lies in a ramp, another goal held across it
        assert any(c.smooth_in <= f <= c.start or c.end <= f <= c.smooth_out
                   for c in cons if not c.start <= f <= c.end)
        assert any(c.start < f < c.end and not c.kind_object.one_sided(c.goal) for c in cons)
    size = figure_size(thrown.composed)
    assert held_glitches(clean.composed, cons, size).tolist() == []
    assert held_glitches(thrown.composed, cons, size).tolist() == list(frames)

    solved = enforce(thrown.composed, cons)
    assert solved.glitches == tuple(frames)
    reference = enforce(clean.composed, cons)
    as_thrown = enforce(thrown.composed, cons, glitches=())
    # the no-pop rule finds what it finds on the clean capture (its limits near the glitch
    # are the glitched conversion's: within a hundredth)
    worst = _worst_pop(performer, clean.composed, reference, cons)
    fixed = _worst_pop(thrown.performer, thrown.composed, solved, cons)
    assert worst["ratio"] <= 1.0
    assert (fixed["joint"], fixed["frame"]) == (worst["joint"], worst["frame"])
    assert fixed["ratio"] == pytest.approx(worst["ratio"], abs=0.01)
    if case == "jump-fair1-tpose":
        # solved from the glitched posture, the legs took the glitch there (1.03 at 391; over
        # 1.5 at 409 until pass one solved the frames that start under a floor from above
        # it too: the thrown body's foot started under it there, and the solve kept a hold)
        popped = _worst_pop(thrown.performer, thrown.composed, as_thrown, cons)
        assert popped["ratio"] > 1.0, popped
        assert min(abs(popped["frame"] - f) for f in frames) <= 1, popped
        # the scene's solve says where (the CLI's --report), and its keys, fitted to the
        # tasks, take the glitch undone as the dense solve has it: every goal held, no pop
        # (keyed through with the rest, the keys fell back to the dense curves; keyed on
        # every joint there, one the dense solve leaves alone, LHipJoint, took it and turned
        # 1.79 times the no-pop limit)
        solution = thrown.solve(regenerate=True)
        assert solution.report["glitches"] == list(frames)
        assert solution.report["keys"]["fitted_to"] == "tasks"
        assert solution.report["quality"]["pops"][0]["ratio"] <= 1.0
        from test_layers import _goal_errors
        assert max(_goal_errors(solution.motion, solution.constraints)) < 1e-3
    # every goal met as in the clean solve
    for i in range(len(cons)):
        assert np.nanmax(solved.residual[i], initial=0.0) < 1e-4 * size
    # at the glitch the figure stands where the clean solve has it (the way between its
    # neighbours: far closer than the glitch threw it), elsewhere it is the clean solve
    p_clean = _positions(reference.motion)
    gap = np.linalg.norm(_positions(solved.motion) - p_clean, axis=-1).max(axis=1)
    thrown_by = np.linalg.norm(_positions(thrown.composed) - _positions(clean.composed),
                               axis=-1).max(axis=1)
    for f in frames:
        assert gap[f] < 0.25 * thrown_by[f], (f, gap[f], thrown_by[f])
    assert np.delete(gap, list(frames)).max() < 1e-4 * size


def test_only_the_cmu_jumps_have_glitches_under_their_contacts():
    """Every shared capture (six conventions, 30 to 120 fps) onto the bundled CMU T-pose
    with its automatic contacts: the CMU jumps' two frames, nothing anywhere else."""
    clips = {f"shared/{n}": shared_path(n) for n in SHARED_BVH}
    clips.update({f"bundled/{n}": clip_path(n) for n in BUNDLED_BVH})
    target_file = clip_path("cmu_rest_tpose.bvh")
    found = {}
    for name, clip in clips.items():
        performer = read_motion(clip)
        if performer.num_frames < 2:                 # a rest pose
            continue
        scene = _scene(performer, clip, target_file)
        composed = scene.composed
        frames = held_glitches(composed, scene.automatic_constraints(), figure_size(composed))
        found[name] = frames.tolist()
    assert len(found) == 12 + 2                      # the rest poses left out
    assert {k: v for k, v in found.items() if v} == {"shared/cmu_mb_01_01_jumps.bvh": [975, 980]}



@pytest.mark.parametrize("target, frames", [
    ("fbx/maya_kenney_character_7700_binary.fbx", [975, 980]),
    ("target_robot_expressive.glb", [975, 980, 1010]),
], ids=["kenney", "robot"])
def test_a_rig_whose_root_never_turns_has_its_body_judged_below_it(target, frames):
    """Kenney's Maya character hangs its hips (``HipsCtrl``) and its feet's controls from a
    ``Root`` the conversion never turns, and the robot its body and feet from ``Bone``: the
    topmost branching joint is that still node, so no frame ever turned out and back there,
    and the CMU jumps' glitches under the planted feet (975 and 980, found on every other
    character) were not found (a pop 1.93 times the no-pop limit on Kenney's at 980). The
    body is judged at the branching joint under the still node's largest child: the same
    two frames (the robot, whose held joints are controls carried with its shins, also 1010,
    as the fox); and the Bandai walk onto them, none."""
    target_file = shared_path(target)
    for clip, expected in (("cmu_mb_01_01_jumps.bvh", frames),
                           ("bandai1_walk_normal_001.bvh", [])):
        clip_file = shared_path(clip)
        scene = _scene(read_motion(clip_file), clip_file, target_file)
        composed = scene.composed
        top = composed.skeleton.body_top()
        assert np.ptp(composed.rotations[:, top], axis=0).max() == 0.0   # a still node
        found = held_glitches(composed, scene.automatic_constraints(), figure_size(composed))
        assert found.tolist() == expected, clip

def test_the_way_between_keeps_everything_but_the_glitch():
    """``without_glitches`` changes the glitch frames only: rotations on the arc between the
    neighbours (a run of two from the frames either side), the root on the line."""
    performer = read_motion(shared_path("cmu_mb_01_01_jumps.bvh"))
    out = without_glitches(performer, [975, 980, 981])
    changed = np.flatnonzero(np.any(out.rotations != performer.rotations, axis=(1, 2)))
    assert changed.tolist() == [975, 980, 981]
    q = out.rotations
    between = angle_between(q[974], q[976])
    assert np.allclose(angle_between(q[975], q[974]), between / 2, atol=1e-7)
    assert np.allclose(angle_between(q[980], q[979]), angle_between(q[979], q[982]) / 3,
                       atol=1e-7)
    t = out.translations[:, 0]
    assert np.allclose(t[975], (t[974] + t[976]) / 2)
    assert np.allclose(t[981], t[979] + 2 * (t[982] - t[979]) / 3)
    assert np.array_equal(out.translations[:, 1:], performer.translations[:, 1:])
    with pytest.raises(ValueError, match="a frame either side"):
        without_glitches(performer, [0])


def test_the_keys_take_the_glitch_undone_where_the_dense_solve_spikes():
    """The solved keys (fitted to the tasks) of the FAIR jump with its two glitches: every
    channel the dense correction spikes at a glitch is keyed on it and either side, so the
    keyed posture there comes near the dense solve's (within 6 mm, and less than half as far
    as keyed through: measured 1.1 and 5.3 mm at 391 and 409 where keyed through is 11 mm
    off at 409); a joint the dense solve leaves alone there (LHipJoint) gets no such keys."""
    from motion_composer.engine.correction import keyfit
    (pw, pn), (tw, tn), frames = CASES["jump-fair1-tpose"]
    performer_file, target_file = _path(pw, pn), _path(tw, tn)
    scene = _scene(_glitched(read_motion(performer_file), frames), performer_file,
                   target_file)
    cons = scene.automatic_constraints()
    dense = enforce(scene.edited, cons)
    assert dense.glitches == frames
    spiked = keyfit.fit_to_tasks(scene.edited, cons, dense.rotvecs, dense.root,
                                 pull=keyfit.FAITHFUL_PULL, glitches=dense.glitches)
    through = keyfit.fit_to_tasks(scene.edited, cons, dense.rotvecs, dense.root,
                                  pull=keyfit.FAITHFUL_PULL)
    p_dense = _positions(dense.motion)
    for f in frames:
        near = [np.linalg.norm(_positions(keys.apply(scene.edited))[f] - p_dense[f],
                               axis=-1).max() for keys in (spiked, through)]
        assert near[0] < 6e-3 and near[1] > 2 * near[0], (f, near)
    # keyed on and beside each glitch: every channel whose dense correction spikes there by
    # over a millimetre at its lever (the fit's tolerance is half of one); not LHipJoint
    from motion_composer.engine.correction.displacement import chain_lengths
    sk = scene.edited.skeleton
    lever = chain_lengths(sk)
    checked = 0
    for (joint, _), curve in spiked.curves.items():
        j = sk.index.get(joint)
        signal, arm = (dense.root, 1.0) if j is None else (dense.rotvecs[:, j], lever[j])
        at = set(np.round(np.asarray(curve.frames)).astype(int).tolist())
        for f in frames:
            if np.linalg.norm(signal[f] - (signal[f - 1] + signal[f + 1]) / 2) * arm > 1e-3:
                assert {f - 1, f, f + 1} <= at, (joint, f)
                checked += 1
        if joint == "LHipJoint":                 # its even keys may fall near one
            assert not any({f - 1, f, f + 1} <= at for f in frames)
    assert checked >= 6
