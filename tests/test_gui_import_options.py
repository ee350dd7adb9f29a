"""File > Import's options dialog: the detected units and up axis shown, overrides chosen,
kept in the project (as ``--performer-units`` ... on the command line)."""
from __future__ import annotations

import pytest

from motion_composer.app.gui.import_options import ImportOptionsDialog
from motion_composer.app.gui.qt import QtWidgets
from gui_support import quiet_window
from conftest import clip_path, shared_path
from detect_cases import renamed, written_in
from motion_composer.engine.formats import read_motion
from motion_composer.engine.project import load_project, save_project

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


@pytest.fixture()
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    return w


@pytest.fixture()
def z_up_mm(tmp_path):
    """The bundled CMU walk as a generic exporter writes it: numbered joints, millimetres,
    Z-up (detected right: the dialog shows it)."""
    path = tmp_path / "walk_mm.bvh"
    path.write_text(written_in(renamed(read_motion(WALK)), "mm", "+Z"))
    return path


def _drive(monkeypatch, steps, shown):
    """Make the dialog's ``exec`` run ``steps(dialog)`` as a user would, then return what
    the buttons give; ``shown`` collects the dialogs."""
    def exec_(dialog):
        shown.append(dialog)
        return steps(dialog)
    monkeypatch.setattr(ImportOptionsDialog, "exec", exec_)


def _choose(combo: QtWidgets.QComboBox, value: str) -> None:
    combo.setCurrentIndex(combo.findData(value))


def test_the_dialog_shows_detection_and_the_choice_is_kept_in_the_project(
        window, monkeypatch, z_up_mm, tmp_path):
    shown = []

    def steps(dialog):
        assert dialog.units.currentText() == "detected (mm)"
        assert dialog.up_axis.currentText() == "detected (+Z)"
        _choose(dialog.units, "cm")                 # the user knows better
        dialog.scale.setText("")
        dialog.accept()
        return dialog.result()
    _drive(monkeypatch, steps, shown)
    window.ask_open_path = lambda caption, filters: str(z_up_mm)
    window.import_dialog("performer")
    assert len(shown) == 1 and not window.errors
    project = window.doc.scene.project
    assert project.performer.units == "cm" and project.performer.up_axis is None
    src = window.doc.scene.performer.skeleton.source
    assert (src.units, src.scale, src.up_axis) == ("cm", 0.01, "+Z")
    window.import_file("target", TPOSE)
    save_project(window.doc.scene.project, tmp_path / "p.mcp")
    assert load_project(tmp_path / "p.mcp").performer.units == "cm"


def test_reimporting_starts_from_the_projects_choice_and_cancel_changes_nothing(
        window, monkeypatch, z_up_mm):
    assert window.import_file("performer", z_up_mm, up_axis="+Y")
    before = window.doc.scene.performer
    shown = []

    def steps(dialog):
        assert dialog.up_axis.currentData() == "+Y"
        dialog.reject()
        return dialog.result()
    _drive(monkeypatch, steps, shown)
    window.ask_open_path = lambda caption, filters: str(z_up_mm)
    window.import_dialog("performer")
    assert len(shown) == 1 and window.doc.scene.performer is before


def test_a_bad_scale_keeps_the_dialog_open_with_the_reason(window, monkeypatch, z_up_mm):
    shown = []

    def steps(dialog):
        dialog.scale.setText("-2")
        dialog.accept()
        assert dialog.result() != QtWidgets.QDialog.DialogCode.Accepted
        assert "positive number" in dialog.error.text()
        dialog.scale.setText("0.001")
        _choose(dialog.position_mode, "absolute")
        dialog.accept()
        return dialog.result()
    _drive(monkeypatch, steps, shown)
    window.ask_open_path = lambda caption, filters: str(z_up_mm)
    window.import_dialog("performer")
    source = window.doc.scene.project.performer
    assert (source.scale, source.position_mode, source.units) == (0.001, "absolute", None)


def test_a_doubtful_file_says_so_in_the_dialog_and_the_status_bar(window, monkeypatch,
                                                                 tmp_path):
    # Bandai's walk written three times too large in centimetres (a 4 m person)
    import dataclasses
    from motion_composer.engine.skeleton import EndSite
    motion = read_motion(shared_path("bandai1_walk_normal_001.bvh"))
    sk = motion.skeleton
    giant = motion.replace(translations=motion.translations * 3, skeleton=dataclasses.replace(
        sk, offsets=sk.offsets * 3,
        end_sites=[EndSite(s.parent, s.offset * 3, s.name) for s in sk.end_sites]))
    path = tmp_path / "giant.bvh"
    path.write_text(written_in(giant, "cm", "+Y"))
    shown = []

    def steps(dialog):
        assert "fits no unit for a person" in dialog.doubt.text()
        dialog.accept()
        return dialog.result()
    _drive(monkeypatch, steps, shown)
    window.ask_open_path = lambda caption, filters: str(path)
    window.import_dialog("performer")
    assert len(shown) == 1
    assert "fits no unit for a person" in window.statusBar().currentMessage()


def test_a_gltf_character_is_imported_without_the_dialog(window, monkeypatch):
    shown = []
    _drive(monkeypatch, lambda dialog: 0, shown)
    window.ask_open_path = lambda caption, filters: str(shared_path(
        "target_robot_expressive.glb"))
    window.import_dialog("target")
    assert shown == [] and window.doc.scene.target is not None and not window.errors


def test_a_gltf_written_z_up_is_offered_its_up_axis_and_stands(window, monkeypatch, tmp_path):
    """Ely written +Z up (Blender's exporter with "+Y Up" unticked): the dialog asks its up
    axis alone, says why, and offers the axis its figure stands along; accepted, the project
    keeps it, the target and its skinned mesh stand along +Y (as Ely written +Y up), and a
    re-import starts from it."""
    import numpy as np
    from motion_composer.engine.formats import read_character
    from test_gltf import z_up_ely
    lying = z_up_ely(tmp_path)
    shown = []

    def steps(dialog):
        assert "stands along +Z" in dialog.doubt.text() and dialog.doubt.isVisibleTo(dialog)
        assert dialog.up_axis.currentData() == "+Z"
        assert not dialog.units.isVisibleTo(dialog) and not dialog.scale.isVisibleTo(dialog)
        dialog.accept()
        return dialog.result()
    _drive(monkeypatch, steps, shown)
    window.ask_open_path = lambda caption, filters: str(lying)
    window.import_dialog("target")
    assert len(shown) == 1 and not window.errors
    scene = window.doc.scene
    assert scene.project.target.up_axis == "+Z"
    assert scene.target.skeleton.source.doubt == ""
    ely = read_character(shared_path("target_mixamo_ely.glb"))
    np.testing.assert_allclose(scene.target.translations, ely.rest_motion().translations,
                               atol=1e-9)
    assert len(scene.character.meshes) == len(ely.meshes)
    for drawn, written_up in zip(scene.character.meshes, ely.meshes):
        np.testing.assert_allclose(drawn.positions, written_up.positions, atol=1e-9)

    def again(dialog):
        assert dialog.up_axis.currentData() == "+Z"
        dialog.reject()
        return dialog.result()
    _drive(monkeypatch, again, shown)
    window.import_dialog("target")
    assert len(shown) == 2 and window.doc.scene is scene
