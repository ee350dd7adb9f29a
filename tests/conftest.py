"""Shared test fixtures: where the real data lives.

``../shared/data`` (beside the repository, or ``$MC_SHARED_DATA``) holds clips that may not be
redistributed; tests that need it skip with a clear reason where it is absent, so the suite
also passes on a fresh machine with only the clips bundled in ``resources/clips``.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
CLIPS = REPO / "resources" / "clips"
SHARED_DATA = Path(os.environ.get("MC_SHARED_DATA", REPO.parent / "shared" / "data"))

#: every BVH file of ../shared/data, by name (the list is fixed so that a missing file fails)
SHARED_BVH = [
    "bandai1_kick_normal_001.bvh",
    "bandai1_run_active_001.bvh",
    "bandai1_walk_normal_001.bvh",
    "bandai2_raise-up-right-hand_normal_001.bvh",
    "cc3_cmu_02_01_walk.bvh",
    "cc3_cmu_02_06_pickup.bvh",
    "cmu_max_131_01_walk.bvh",
    "cmu_mb_01_01_jumps.bvh",
    "cmu_xia_angry_13_000_run.bvh",
    "fair1_child5_wave_hello.bvh",
    "fair1_child8_jumping.bvh",
    "rokoko_mixamo_jesse_dance.bvh",
    "target_cmu_mb_rest_tpose.bvh",
]

#: clips shipped in resources/clips (freely licensed), always present
BUNDLED_BVH = ["cmu_131_01_walk.bvh", "fair1_child8_jumping.bvh", "cmu_rest_tpose.bvh"]


def shared_path(name: str) -> Path:
    """Path of a file in ../shared/data, or skip the test saying why."""
    path = SHARED_DATA / name
    if not SHARED_DATA.is_dir():
        pytest.skip(f"../shared/data is absent ({SHARED_DATA}); this test needs its clips, "
                    "which may not be redistributed")
    if not path.is_file():
        pytest.fail(f"{name} is missing from {SHARED_DATA}")
    return path


def clip_path(name: str) -> Path:
    """Path of a bundled clip in resources/clips."""
    return CLIPS / name


def all_bvh_params():
    """pytest params for every BVH we test on: the bundled clips, then the shared ones."""
    return ([pytest.param(("bundled", n), id=f"bundled/{n}") for n in BUNDLED_BVH] +
            [pytest.param(("shared", n), id=n) for n in SHARED_BVH])


def resolve(spec) -> Path:
    kind, name = spec
    return clip_path(name) if kind == "bundled" else shared_path(name)
