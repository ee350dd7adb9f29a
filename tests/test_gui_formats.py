"""The window imports and exports through engine.formats: by content, with its dialog filters."""
from __future__ import annotations

import shutil

import pytest

from motion_composer.app.gui.export_dialog import ExportOptions
from motion_composer.app.gui.qt import QtCore  # noqa: F401  (Qt set up before the widgets)
from gui_support import quiet_window
from conftest import clip_path, shared_path
from motion_composer.engine.formats import (open_filters, read_character, read_motion,
                                            save_filters, sniff)

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.ask_export_options = lambda motion: ExportOptions()      # File > Export's defaults
    return w


def test_the_dialogs_get_the_registry_filters(window, tmp_path):
    asked = []
    window.ask_open_path = lambda caption, filters: asked.append(filters) or ""
    window.import_dialog("performer")
    assert asked == [open_filters()]
    window.import_file("performer", WALK)
    window.import_file("target", TPOSE)
    window.ask_save_path = lambda caption, filters: asked.append(filters) or str(tmp_path / "take")
    window.export_dialog()
    assert asked[-1] == save_filters()
    assert read_motion(tmp_path / "take.bvh").num_frames == 994    # no suffix typed: BVH


def test_files_import_by_content_whatever_their_name(window, tmp_path):
    clip = tmp_path / "walk.txt"
    shutil.copy(WALK, clip)
    avatar = tmp_path / "robot.vrm"
    shutil.copy(shared_path("target_robot_expressive.glb"), avatar)
    assert window.import_file("performer", clip), window.errors
    assert window.import_file("target", avatar), window.errors
    doc = window.doc
    assert doc.scene.performer.num_frames == 994 and doc.scene.ready
    assert doc.scene.character is not None and doc.scene.character.meshes
    out = tmp_path / "onto.glb"
    assert window.export_motion(out), window.errors
    assert sniff(out).mesh and read_character(out).num_vertices == doc.scene.character.num_vertices


def test_a_gltf_performer_and_fbx_are_refused_with_a_message(window, tmp_path):
    robot = shared_path("target_robot_expressive.glb")
    assert not window.import_file("performer", robot)
    assert "character" in window.errors[-1] and "target" in window.errors[-1]
    rig = tmp_path / "rig.fbx"
    rig.write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + bytes(64))
    assert not window.import_file("target", rig)
    assert "rig.fbx" in window.errors[-1] and "FBX" in window.errors[-1]


def test_an_export_to_an_unknown_suffix_is_refused(window, tmp_path):
    window.import_file("performer", WALK)
    window.import_file("target", TPOSE)
    out = tmp_path / "take.txt"
    assert not window.export_motion(out)
    assert "cannot write" in window.errors[-1] and not out.exists()


def test_a_lying_gltf_target_is_said_in_the_status_bar(window, tmp_path):
    """A glTF written +Z up, imported without its up axis (dropped on the window, or the
    import dialog's "as the file says"): the status bar says so, with the hint to set the up
    axis on import again."""
    from test_gltf import z_up_ely
    lying = z_up_ely(tmp_path)
    window.import_file("performer", WALK)
    assert window.import_file("target", lying)
    doubt = read_character(lying).skeleton.source.doubt
    assert doubt and window.statusBar().currentMessage() == (
        f"{lying.name}: {doubt}; if that is wrong, import it again and set it in the options")
    assert window.errors == []
