"""FBX in the window: the import dialog offers it (its filters come from the registry), an FBX
character as the target is drawn as a skinned mesh that follows the motion and exports as
GLB with its mesh, and an FBX take imports as the performer."""
from __future__ import annotations

import numpy as np

from motion_composer.app.gui.qt import QtCore  # noqa: F401  (Qt set up before the widgets)
from conftest import shared_path
from gui_support import quiet_window, skinned_character_in_window
from motion_composer.engine.formats import open_filters


def test_an_fbx_character_is_drawn_as_a_skinned_mesh_that_follows_the_motion(qtbot, tmp_path):
    mixamo = shared_path("fbx/mixamo.fbx")
    doc, _v, first, second, back = skinned_character_in_window(qtbot, tmp_path, mixamo)
    assert first.shape == second.shape and first.shape[0] == 24746
    assert np.abs(first - second).max() > 0.05            # the mesh moves with the motion
    assert back.skeleton.names == doc.scene.target.skeleton.names
    assert back.num_vertices == 24746


def test_an_fbx_take_imports_as_the_performer(qtbot, tmp_path, monkeypatch):
    assert "*.fbx" in open_filters()
    window = quiet_window(qtbot, tmp_path, monkeypatch)
    samba = shared_path("fbx/Samba_Dancing.fbx")
    assert window.ask_import_options("performer", samba) == {}
    assert window.import_file("performer", samba), window.errors
    performer = window.doc.scene.performer
    assert performer.num_frames == 595 and performer.name == "mixamo.com"
    maya = shared_path("fbx/maya_character_7500_binary.fbx")
    assert not window.import_file("performer", maya)       # no take: a target only
    assert "no take that moves a joint" in window.errors[-1]
