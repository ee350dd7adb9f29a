"""The streamed direct conversion (``transfer``, what ``retarget`` runs) against the staged one
(``convert`` then ``compose``, what the scene caches): the same motion bit for bit, on every
clip, whatever the number of runs of frames it is cut into."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine import read_bvh
from motion_composer.engine.conversion import (BindOptions, RootOptions, bind, compose, convert,
                                               retarget, transfer)
from motion_composer.engine.conversion import converter
from motion_composer.engine.conversion.automap import automap
from motion_composer.engine.errors import MappingError
from conftest import all_bvh_params, clip_path, resolve, shared_path

TARGETS = ["bandai1_walk_normal_001.bvh", "cc3_cmu_02_06_pickup.bvh"]


def _same(a, b):
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)
    assert a.skeleton is b.skeleton and a.frame_time == b.frame_time


@pytest.mark.parametrize("target_name", TARGETS)
@pytest.mark.parametrize("spec", all_bvh_params())
def test_transfer_is_convert_then_compose(spec, target_name):
    performer = read_bvh(resolve(spec))
    target = read_bvh(shared_path(target_name))
    try:
        corr = automap(target.skeleton, performer.skeleton)
    except MappingError:
        pytest.skip(f"no automatic map from {spec[1]} onto {target_name}")
    for root, distribute in [(RootOptions(), "even"), (RootOptions("absolute"), "first"),
                             (RootOptions("in-place", scale=(0.5, 2.0)), "even")]:
        binding = bind(performer, target, corr, BindOptions(distribute=distribute))
        staged = compose(binding, convert(binding, performer, root), performer.frame_time)
        _same(transfer(binding, performer, root), staged)


def test_runs_of_frames_do_not_change_the_result(monkeypatch):
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    target = read_bvh(clip_path("fair1_child8_jumping.bvh"))
    corr = automap(target.skeleton, performer.skeleton)
    whole = retarget(performer, target, corr)
    monkeypatch.setattr(converter, "_CHUNK", 97)        # 994 frames: ten runs and a short one
    steps = []
    _same(retarget(performer, target, corr, progress=steps.append), whole)
    assert len(steps) == 11 and steps[-1] == 1.0 and steps == sorted(steps)
    binding = bind(performer, target, corr)
    _same(compose(binding, convert(binding, performer), performer.frame_time), whole)
    assert whole.name == "cmu_131_01_walk_on_fair1_child8_jumping"


def test_transfer_refuses_another_performer():
    performer = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    other = read_bvh(clip_path("fair1_child8_jumping.bvh"))
    binding = bind(performer, other, automap(other.skeleton, performer.skeleton))
    with pytest.raises(MappingError, match="another performer"):
        transfer(binding, other)
