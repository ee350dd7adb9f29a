"""The scene (engine/scene.py): one model from which everything is derived, lazily and once.

Real clips throughout: the bundled CMU walk onto the bundled CMU T-pose character, and onto
Bandai and CC3 skeletons from ../shared/data where it is present. The tests read
``scene.derived.computed`` (how many times each stage ran) to show that an edit recomputes
only what it touches, measure with :mod:`tracemalloc` what an undo history of 200 edits on a
long clip holds, check that the scene, the command line and a saved project are one pipeline,
and that :func:`~engine.scene.remap` keeps the pairs set by hand.
"""
from __future__ import annotations

import tracemalloc
from collections import Counter

import numpy as np
import pytest

from motion_composer.app.cli import main as cli_main
from conftest import clip_path, shared_path
from motion_composer.engine.conversion import BindOptions, RootOptions
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.conversion.correspondence import BY_HAND, Correspondence
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.displacement import Curve, DisplacementMap
from motion_composer.engine.formats import read_motion, read_performer, write_motion
from motion_composer.engine.motion import Motion
from motion_composer.engine.project import Project, Source, open_project, save_project
from motion_composer.engine.scene import Scene, evaluate_project, remap
from ik_fixtures import MAX_TO_HOLDEN

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
STAGES = ("binding", "intermediate", "composed", "motion")


def walk_scene() -> Scene:
    """The walk on the T-pose character, mapped by hand, its motion evaluated once."""
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN))
    scene = Scene.from_project(project)
    assert scene.motion is not None
    return scene


def hand_constraint(frame: int, x: float = 0.25) -> Constraint:
    return Constraint(joint="LeftHand", kind="position", goal={"point": [x, 1.2, 0.2]},
                      smooth_in=frame - 20, start=frame, end=frame + 20,
                      smooth_out=frame + 40, name=f"hand at {frame}")


def head_curve(value: float) -> DisplacementMap:
    return DisplacementMap({("Head", "ry"): Curve([0.0, 200.0, 400.0], [0.0, value, 0.0],
                                                  ("smooth",) * 3)})


def runs(scene: Scene, edited: Scene) -> dict:
    """The stages ``edited.motion`` ran beyond what ``scene`` had run (one shared store)."""
    assert edited.derived is scene.derived
    before = Counter(scene.derived.computed)
    assert edited.motion is not None
    return {stage: edited.derived.computed[stage] - before[stage] for stage in STAGES}


# --------------------------------------------------------------------------- what an edit runs
def test_a_constraint_edit_binds_converts_and_composes_nothing():
    scene = walk_scene()
    edited = scene.replace(constraints=(hand_constraint(400),))
    ran = runs(scene, edited)
    print("constraint edit ran", ran)
    assert ran == {"binding": 0, "intermediate": 0, "composed": 0, "motion": 0}
    assert edited.motion is scene.motion


def test_a_displacement_edit_only_reapplies_the_map():
    scene = walk_scene()
    edited = scene.replace(displacement=head_curve(0.3))
    ran = runs(scene, edited)
    print("displacement edit ran", ran)
    assert ran == {"binding": 0, "intermediate": 0, "composed": 0, "motion": 1}
    assert edited.composed is scene.composed
    assert not np.array_equal(edited.motion.rotations, scene.motion.rotations)


def test_a_mapping_edit_rebinds():
    scene = walk_scene()
    edited = scene.replace(correspondence=scene.correspondence.with_pair("Neck1", None))
    ran = runs(scene, edited)
    print("mapping edit ran", ran)
    assert ran == {"binding": 1, "intermediate": 1, "composed": 1, "motion": 1}
    assert edited.binding is not scene.binding


def test_a_bind_option_edit_rebinds():
    scene = walk_scene()
    edited = scene.replace(bind_options=BindOptions(distribute="first"))
    ran = runs(scene, edited)
    print("bind option edit ran", ran)
    assert ran == {"binding": 1, "intermediate": 1, "composed": 1, "motion": 1}


def test_a_root_option_edit_reconverts_without_rebinding():
    scene = walk_scene()
    edited = scene.replace(root=RootOptions(mode="scaled", scale=(1.1, 0.9)))
    ran = runs(scene, edited)
    print("root option edit ran", ran)
    assert ran == {"binding": 0, "intermediate": 1, "composed": 1, "motion": 1}
    assert edited.binding is scene.binding
    assert not np.array_equal(edited.motion.translations, scene.motion.translations)


def test_undo_goes_back_to_cached_results():
    """Back to earlier scene objects (undo, then redo): nothing runs again."""
    first = walk_scene()
    history = [first]
    for change in ({"root": RootOptions(mode="in-place")},
                   {"correspondence": first.correspondence.with_pair("Neck1", None)},
                   {"displacement": head_curve(0.2)}):
        history.append(history[-1].replace(**change))
        assert history[-1].motion is not None
    motions = [s.motion for s in history]
    before = Counter(first.derived.computed)
    for scene, motion in zip(reversed(history), reversed(motions)):       # undo to the start
        assert scene.motion is motion
    for scene, motion in zip(history, motions):                           # redo to the end
        assert scene.motion is motion
    assert first.derived.computed == before


# --------------------------------------------------------------------------- memory
def tiled(motion: Motion, frames: int) -> Motion:
    """``motion`` repeated to ``frames`` frames (a long take made of a real clip)."""
    reps = -(-frames // motion.num_frames)
    return Motion(motion.skeleton, np.tile(motion.rotations, (reps, 1, 1))[:frames].copy(),
                  np.tile(motion.translations, (reps, 1, 1))[:frames].copy(),
                  motion.frame_time, motion.name)


def test_an_undo_history_of_200_edits_on_a_long_clip_stays_small():
    """200 edits on 10,000 frames, alternating constraint and displacement edits, every scene
    kept (as the undo stack keeps them), the motion evaluated after each: under 200 MB more."""
    performer = tiled(read_performer(WALK), 10_000)
    target = read_motion(TPOSE)
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=Correspondence(MAX_TO_HOLDEN))
    scene = Scene(project, performer, target)
    assert scene.motion.num_frames == 10_000
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        history = [scene]
        for i in range(200):
            s = history[-1]
            if i % 2:
                s = s.replace(displacement=head_curve(0.001 * i))
            else:
                s = s.replace(constraints=s.constraints + (hand_constraint(100 + 45 * i),))
            assert s.motion is not None
            history.append(s)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    mb = 1024 * 1024
    print(f"200 edits on 10,000 frames: {(current - base) / mb:.1f} MB held, "
          f"{(peak - base) / mb:.1f} MB peak; runs {dict(scene.derived.computed)}")
    assert len(history) == 201
    assert scene.derived.computed["binding"] == 1 and scene.derived.computed["composed"] == 1
    assert peak - base < 200 * mb and current - base < 200 * mb


# --------------------------------------------------------------------------- one pipeline
def test_solve_is_the_command_line_and_a_saved_project(tmp_path):
    """``Scene.solve(regenerate=True)`` = ``retarget --auto-contacts --floor 0``: the same
    constraints, the same written motion; the saved solved project evaluates to the scene's
    motion bit for bit."""
    out, saved = tmp_path / "cli.bvh", tmp_path / "cli.mcp"
    assert cli_main(["retarget", str(WALK), "--target", str(TPOSE), "-o", str(out),
                     "--auto-contacts", "--floor", "0", "--save-project", str(saved)]) == 0

    performer, target = read_performer(WALK), read_motion(TPOSE)
    project = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True, floor=0.0)
    solution = Scene.from_project(project).solve(regenerate=True)

    mine = tmp_path / "scene.bvh"
    write_motion(solution.motion, mine)
    assert mine.read_bytes() == out.read_bytes()

    cli_project, cli_performer, cli_target = open_project(saved)
    assert [c.to_dict() for c in cli_project.constraints] == \
        [c.to_dict() for c in solution.constraints]
    assert any(c.auto and c.kind == "plane" for c in solution.constraints)
    assert any(c.auto and c.meta.get("source") == "contact" for c in solution.constraints)

    ours = tmp_path / "scene.mcp"
    save_project(solution.scene.project, ours)
    loaded = open_project(ours)
    evaluated = evaluate_project(*loaded).motion
    for result in (evaluated, evaluate_project(cli_project, cli_performer, cli_target).motion):
        assert np.array_equal(result.rotations, solution.scene.motion.rotations)
        assert np.array_equal(result.translations, solution.scene.motion.translations)


# --------------------------------------------------------------------------- remap
def hand_and_auto_map(target, performer) -> Correspondence:
    """The automatic map with hand edits: a pair without a note naming a performer joint the
    automatic map gave another target joint, one noted "set by hand", and the left toe (a
    pair without a note) left as the automatic map had it."""
    auto = automap(target.skeleton, performer.skeleton)
    pairs = dict(auto.pairs)
    notes = dict(auto.notes)
    assert "Head" in pairs and "Neck1" in pairs
    pairs.pop("Neck1")
    pairs["Neck"] = "Neck"                          # the performer's neck drives the target's
    notes.pop("Neck", None)
    notes.pop("Neck1", None)
    notes["Head"] = BY_HAND
    notes.pop("LeftToeBase")
    return Correspondence(pairs, notes)


def one_to_one(correspondence: Correspondence) -> bool:
    values = list(correspondence.pairs.values())
    return len(values) == len(set(values))


def test_remap_keeps_hand_pairs_and_automaps_the_rest():
    performer, target = read_performer(WALK), read_motion(TPOSE)
    auto = automap(target.skeleton, performer.skeleton)
    edited = hand_and_auto_map(target, performer)
    # an automatic pair moved by the map's edits is redone; a hand pair is kept
    stale = dict(edited.pairs)
    stale["LeftHand"] = "RightWrist"
    notes = dict(edited.notes, LeftHand="auto-mapped")
    stale.pop("RightHand")
    remapped = remap(Correspondence(stale, notes), target.skeleton, performer.skeleton)
    assert remapped.pairs["Neck"] == "Neck" and remapped.set_by_hand("Neck")
    assert remapped.pairs["Head"] == auto.pairs["Head"] and remapped.notes["Head"] == BY_HAND
    assert remapped.pairs["LeftHand"] == auto.pairs["LeftHand"]
    assert remapped.pairs["RightHand"] == auto.pairs["RightHand"]
    assert not remapped.set_by_hand("LeftHand")
    assert one_to_one(remapped)
    # the performer's Neck is taken by hand, so the target joint automap gave it stays free
    taken = [t for t, p in auto.pairs.items() if p == "Neck" and t != "Neck"]
    assert all(t not in remapped.pairs for t in taken)
    remapped.validate(target.skeleton, performer.skeleton)


@pytest.mark.shared_data
@pytest.mark.parametrize("name", ["bandai1_walk_normal_001.bvh", "cc3_cmu_02_01_walk.bvh"])
def test_replacing_the_target_by_another_convention_remaps(name):
    """CMU target replaced by a Bandai or CC3 skeleton: the hand pairs whose joints the new
    target has are kept, the rest auto-mapped; the map validates and binds."""
    performer, target = read_performer(WALK), read_motion(TPOSE)
    scene = Scene.from_project(Project(
        performer=Source(str(WALK)), target=Source(str(TPOSE)),
        correspondence=hand_and_auto_map(target, performer)))
    assert scene.motion is not None
    path = shared_path(name)
    other = read_motion(path)
    moved = scene.with_source("target", other, Source(str(path)))
    corr = moved.correspondence
    assert moved.target is other and moved.project.target.path == str(path)
    for t, p in scene.correspondence.pairs.items():
        if scene.correspondence.set_by_hand(t) and t in other.skeleton.index:
            assert corr.pairs.get(t) == p, t
    assert all(t in other.skeleton.index for t in corr.pairs)
    assert "LeftToeBase" not in corr.pairs               # a hand pair whose joint is gone
    assert "LeftToe" in corr.pairs.values()              # its performer joint auto-mapped
    assert len(corr) >= 12 and one_to_one(corr)
    corr.validate(other.skeleton, performer.skeleton)
    assert moved.evaluation_error == ""
    assert moved.binding is not None and moved.motion.num_frames == performer.num_frames
    assert moved.motion.skeleton is other.skeleton or \
        moved.motion.skeleton.names == other.skeleton.names


def test_a_character_written_again_is_read_again_for_where_it_stands(tmp_path):
    """The lift stands the conversion on the floor from where the character's mesh puts its
    feet. A glTF character written again to the same path (its mesh 10 cm lower, as after a
    re-export) and imported again into a scene sharing the old one's cache is read again: it
    stands 10 cm lower and the floor raises it 10 cm more."""
    import dataclasses
    import os
    import shutil
    from motion_composer.engine.formats import read_character
    path = tmp_path / "ely.glb"
    shutil.copy(shared_path("target_mixamo_ely.glb"), path)
    character = read_character(path)
    target = character.rest_motion()
    performer = read_performer(WALK)
    scene = Scene(Project(performer=Source(str(WALK)), target=Source(str(path)),
                          correspondence=automap(target.skeleton, performer.skeleton),
                          floor=0.0), performer, target)
    before = scene.standing_floor()
    assert abs(before) < 0.01 and scene.lift() == pytest.approx(-before)
    lowered = dataclasses.replace(character, meshes=[
        dataclasses.replace(m, positions=m.positions - [0.0, 0.1, 0.0])
        for m in character.meshes])
    write_motion(target, tmp_path / "new.glb", lowered)
    os.replace(tmp_path / "new.glb", path)
    again = read_character(path).rest_motion()
    reimported = scene.with_source("target", again, Source(str(path)))
    assert reimported.derived is scene.derived                    # the cache is shared
    assert reimported.standing_floor() == pytest.approx(before - 0.1, abs=1e-4)
    assert reimported.lift() == pytest.approx(0.1 - before, abs=1e-4)
