"""The bundled demo project (resources/demo/demo.mcp) is what resources/demo/make_demo.py builds
with this engine: a change to the conversion, the contacts or the IK that changes the demo's
solve must rebuild it (``python resources/demo/make_demo.py``), or the composer opens on keys
and contacts an older engine fitted (loading a project does not solve it again)."""
from __future__ import annotations

import importlib.util

import numpy as np

from conftest import REPO
from motion_composer.engine.project import load_project

DEMO = REPO / "resources" / "demo"


def _build():
    spec = importlib.util.spec_from_file_location("make_demo", DEMO / "make_demo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build()


def test_the_bundled_demo_is_what_make_demo_builds_with_this_engine():
    stored, built = load_project(DEMO / "demo.mcp"), _build()
    hint = "rebuild it: python resources/demo/make_demo.py"
    # the constraints: the same joints, kinds, ranges and goals
    assert len(stored.constraints) == len(built.constraints), hint
    for a, b in zip(stored.constraints, built.constraints):
        assert (a.joint, a.kind, a.name, a.priority) == (b.joint, b.kind, b.name, b.priority), hint
        assert (a.smooth_in, a.start, a.end, a.smooth_out) == \
            (b.smooth_in, b.start, b.end, b.smooth_out), (a.name, hint)
        assert sorted(a.goal) == sorted(b.goal), (a.name, hint)
        for field in a.goal:
            if isinstance(a.goal[field], str):
                assert a.goal[field] == b.goal[field], (a.name, field, hint)
                continue
            np.testing.assert_allclose(np.asarray(a.goal[field], dtype=float),
                                       np.asarray(b.goal[field], dtype=float),
                                       rtol=0, atol=1e-6, err_msg=f"{a.name} {field}: {hint}")
    # the solved layer: the same channels, key frames, values, slopes and tangents
    a, b = dict(stored.displacement.curves), dict(built.displacement.curves)
    assert a and sorted(a) == sorted(b), hint
    for key in a:
        ca, cb = a[key], b[key]
        np.testing.assert_array_equal(ca.frames, cb.frames, err_msg=f"{key}: {hint}")
        assert (ca.interpolation, ca.tangents) == (cb.interpolation, cb.tangents), (key, hint)
        np.testing.assert_allclose(ca.values, cb.values, rtol=0, atol=1e-6,
                                   err_msg=f"{key}: {hint}")
        np.testing.assert_allclose(ca.slopes, cb.slopes, rtol=0, atol=1e-6,
                                   err_msg=f"{key}: {hint}")
    # and the animator's layers and the view it opens on
    assert [layer.name for layer in stored.layers] == [layer.name for layer in built.layers]
    assert stored.viewer.current_frame == built.viewer.current_frame == 560
