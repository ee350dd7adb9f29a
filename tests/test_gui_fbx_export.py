"""The window's File > Export writes FBX when the chosen name ends in .fbx (the save filters
come from the registry), with the target character's mesh and skin."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.app.gui.export_dialog import ExportOptions
from motion_composer.app.gui.qt import QtCore  # noqa: F401  (Qt set up before the widgets)
from gui_support import quiet_window
from conftest import REPO, clip_path
from motion_composer.engine.formats import save_filters
from motion_composer.engine.formats.fbx.binary import parse_binary

WALK = clip_path("cmu_131_01_walk.bvh")
CHARACTER = REPO / "resources" / "characters" / "test_character.glb"


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.ask_export_options = lambda motion: ExportOptions(frames=(0, 29))
    return w


def test_export_dialog_writes_fbx_with_the_characters_mesh(window, tmp_path):
    assert any(entry.endswith(" (*.fbx)") for entry in save_filters().split(";;"))
    assert window.import_file("performer", WALK), window.errors
    assert window.import_file("target", CHARACTER), window.errors
    out = tmp_path / "onto.fbx"
    window.ask_save_path = lambda caption, filters: str(out)
    window.export_dialog()
    assert not window.errors
    objects = parse_binary(out.read_bytes()).find("Objects").children
    limbs = [o for o in objects if o.name == "Model" and o.props[2] == "LimbNode"]
    assert len(limbs) == window.doc.scene.character.skeleton.num_joints
    (geometry,) = [o for o in objects if o.name == "Geometry"]
    vertices = geometry.find("Vertices").props[0]
    assert len(vertices) == 3 * window.doc.scene.character.num_vertices
    curve = next(o for o in objects if o.name == "AnimationCurve")
    assert len(curve.find("KeyTime").props[0]) == 30
    assert np.all(np.isfinite(vertices))
