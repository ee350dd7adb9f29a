"""Batch retargeting: many clips, one recipe, parallel processes or a Dask cluster."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine import read_bvh
from motion_composer.engine.batch import Recipe, process_clip, run_batch
from conftest import clip_path, shared_path

TPOSE = str(clip_path("cmu_rest_tpose.bvh"))


def _clips():
    return [str(clip_path("cmu_131_01_walk.bvh")), str(clip_path("fair1_child8_jumping.bvh"))]


def test_each_clip_is_written_and_a_bad_clip_does_not_stop_the_rest(tmp_path):
    broken = tmp_path / "broken.bvh"
    text = clip_path("cmu_131_01_walk.bvh").read_text()
    broken.write_text(text[: len(text) // 3])                       # truncated
    clips = [_clips()[0], str(broken), _clips()[1], str(tmp_path / "absent.bvh")]
    seen = []
    summary = run_batch(Recipe(TPOSE, auto_contacts=True), clips, tmp_path / "out", workers=2,
                        progress=lambda done, total, s: seen.append((done, total, s["status"])))
    assert [s["status"] for s in summary] == ["written", "failed", "written", "failed"]
    assert "broken.bvh" in summary[1]["reason"] and "\n" not in summary[1]["reason"]
    assert "no such file" in summary[3]["reason"]
    assert sorted(d for d, _, _ in seen) == [1, 2, 3, 4] and all(t == 4 for _, t, _ in seen)
    for s, clip in ((summary[0], clips[0]), (summary[2], clips[2])):
        out = read_bvh(s["output"])
        assert out.num_frames == read_bvh(clip).num_frames
        assert out.skeleton.names == read_bvh(TPOSE).skeleton.names
        assert s["max_residual_m"] < 1e-3
        assert s["contact_drift"]["corrected_mean_m"] < 0.1 * s["contact_drift"]["direct_mean_m"]


def test_processes_give_the_same_files_as_one_process(tmp_path):
    recipe = Recipe(TPOSE, auto_contacts=False, suffix="_on_cmu")
    one = run_batch(recipe, _clips(), tmp_path / "a", workers=1)
    two = run_batch(recipe, _clips(), tmp_path / "b", workers=2)
    for x, y in zip(one, two):
        assert x["output"].endswith("_on_cmu.bvh")
        assert open(x["output"]).read() == open(y["output"]).read()


def test_a_fixed_mapping_is_validated_per_clip(tmp_path):
    from ik_fixtures import MAX_TO_HOLDEN
    summary = run_batch(Recipe(TPOSE, pairs=MAX_TO_HOLDEN, auto_contacts=False), _clips(),
                        tmp_path, workers=1)
    # the 3dsMax names fit the walk; the FAIR1 clip has other names: a clear failure
    assert summary[0]["status"] == "written"
    assert summary[1]["status"] == "failed"
    assert "not a joint of the performer" in summary[1]["reason"]


def test_clips_of_other_skeletons_map_automatically(tmp_path):
    clip = str(shared_path("bandai1_walk_normal_001.bvh"))
    s = process_clip(Recipe(TPOSE, auto_contacts=True), clip, str(tmp_path))
    assert s["status"] == "written", s["reason"]


@pytest.mark.slow
def test_on_a_local_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed", reason="Dask is not installed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        summary = run_batch(Recipe(TPOSE, auto_contacts=True), _clips() + ["/nope.bvh"],
                            tmp_path, scheduler=cluster.scheduler_address)
    assert [s["status"] for s in summary] == ["written", "written", "failed"]
    local = process_clip(Recipe(TPOSE, auto_contacts=True), _clips()[0], str(tmp_path / "l"))
    assert np.allclose(read_bvh(summary[0]["output"]).rotations,
                       read_bvh(local["output"]).rotations)


def test_the_batch_command_applies_a_project(tmp_path, capsys):
    import json
    from motion_composer.app.cli import main
    from conftest import REPO
    demo = REPO / "resources" / "demo" / "demo.mcp"
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    summary = tmp_path / "summary.json"
    code = main(["batch", str(demo), _clips()[0], str(bad), "-o", str(tmp_path / "out"),
                 "--workers", "2", "--summary", str(summary), "--suffix", "_child"])
    out, err = capsys.readouterr()
    assert code == 1                                        # one clip failed
    assert "1 of 2 clips written" in out and "failed   bad.bvh: " in out
    assert "2/2" in err                                     # the progress bar reached the end
    data = json.loads(summary.read_text())
    assert [s["status"] for s in data] == ["written", "failed"]
    written = read_bvh(data[0]["output"])
    assert data[0]["output"].endswith("cmu_131_01_walk_child.bvh")
    assert written.skeleton.names == read_bvh(clip_path("fair1_child8_jumping.bvh")).skeleton.names
    # the project's automatic contacts were applied to the new clip
    assert data[0]["contact_drift"]["count"] > 5
