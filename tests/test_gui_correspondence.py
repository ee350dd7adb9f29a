"""The correspondence editor, with real widgets on real clips.

Built from a document holding the bundled CMU walk (performer) and the CMU rest T-pose
(target): document changes must show in the widgets (trees, marks, table, lines, labels), and
widget actions (clicks, drops, the table's combo box, buttons) must change the document through
one undoable command each. The panel needs no OpenGL: it runs on the offscreen platform as well
as under Xvfb (pytest-xvfb).
"""
from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest

if not os.environ.get("DISPLAY") and not os.environ.get("QT_QPA_PLATFORM"):
    os.environ["QT_QPA_PLATFORM"] = "offscreen"     # no X server and no pytest-xvfb

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from motion_composer.app.gui.qt import QtCore, QtGui, QtWidgets  # noqa: E402
from motion_composer.app.gui.commands import push_correspondence, push_pair, push_sources  # noqa: E402
from motion_composer.app.gui.correspondence_panel import (CorrespondencePanel, JointTree,  # noqa: E402
                                          required_joints)
from motion_composer.app.gui.document import Document  # noqa: E402
from motion_composer.engine.formats.bvh import read_bvh  # noqa: E402
from tests.conftest import clip_path, shared_path  # noqa: E402
from gui_support import WAIT_MS, shown  # noqa: E402

automap_module = pytest.importorskip("motion_composer.engine.conversion.automap")

Qt = QtCore.Qt
LEFT = Qt.MouseButton.LeftButton


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def clips():
    return (read_bvh(clip_path("cmu_131_01_walk.bvh")),
            read_bvh(clip_path("cmu_rest_tpose.bvh")))


@pytest.fixture
def doc(clips):
    performer, target = clips
    document = Document()
    push_sources(document, performer=performer, performer_path=clip_path("cmu_131_01_walk.bvh"),
                 target=target, target_path=clip_path("cmu_rest_tpose.bvh"))
    yield document
    document.close()


@pytest.fixture
def panel(qtbot, doc):
    return shown(qtbot, CorrespondencePanel(doc), 560, 800)


def auto(doc):
    return automap_module.automap(doc.scene.target.skeleton, doc.scene.performer.skeleton)


def click_joint(qtbot, tree: JointTree, name: str) -> None:
    item = tree.items[name]
    tree.scrollToItem(item)
    rect = tree.visualItemRect(item)
    qtbot.mouseClick(tree.viewport(), LEFT, pos=rect.center())


def drop(tree: JointTree, on: str, side: str, name: str) -> QtGui.QDropEvent:
    """Drop joint ``name`` of tree ``side`` on ``on``'s row of ``tree``, through the tree's own
    drag-move and drop handlers."""
    tree.scrollToItem(tree.items[on])
    pos = QtCore.QPointF(tree.visualItemRect(tree.items[on]).center())
    mime = JointTree.mime_data(side, name)
    with warnings.catch_warnings():         # PySide marks the (only) constructor deprecated
        warnings.simplefilter("ignore", DeprecationWarning)
        move = QtGui.QDragMoveEvent(pos.toPoint(), Qt.DropAction.LinkAction, mime, LEFT,
                                    Qt.KeyboardModifier.NoModifier)
    tree.dragMoveEvent(move)
    assert move.isAccepted() == (side != tree.side)
    event = QtGui.QDropEvent(pos, Qt.DropAction.LinkAction, mime, LEFT,
                             Qt.KeyboardModifier.NoModifier)
    tree.dropEvent(event)
    return event


def pairs_drawn(panel) -> dict[str, str]:
    return {t: p for t, p, *_ in panel.links.segments()}


# ---------------------------------------------------------------------------- building
def test_panel_builds_from_the_document(panel, doc):
    assert list(panel.target_tree.items) == list(doc.scene.target.skeleton.names)
    assert list(panel.performer_tree.items) == list(doc.scene.performer.skeleton.names)
    assert panel.target_tree.headerItem().text(0) == "Target: cmu_rest_tpose"
    assert panel.performer_tree.headerItem().text(0) == "Performer: cmu_131_01_walk"
    # hierarchy: LeftArm hangs from LeftShoulder
    assert panel.target_tree.items["LeftArm"].parent() is panel.target_tree.items["LeftShoulder"]
    assert panel.model.rowCount() == 0
    assert panel.links.segments() == []
    assert panel.automap_action.isEnabled()
    assert not panel.map_action.isEnabled()
    assert not panel.unmap_action.isEnabled() and not panel.clear_action.isEnabled()
    assert "0 of 31 target joints mapped" in panel.summary_label.text()


def test_empty_document_then_sources(qtbot, clips):
    doc = Document()
    panel = CorrespondencePanel(doc)
    qtbot.addWidget(panel)
    assert panel.target_tree.topLevelItemCount() == 0
    assert not panel.automap_action.isEnabled()
    panel.auto_map()                                 # nothing to map: no command, no error
    assert doc.undo_stack.count() == 0
    performer, target = clips
    push_sources(doc, performer=performer, target=target)
    assert len(panel.target_tree.items) == target.skeleton.num_joints
    assert panel.automap_action.isEnabled()
    doc.undo_stack.undo()                            # the trees follow the sources back
    assert panel.target_tree.topLevelItemCount() == 0
    assert panel.performer_tree.headerItem().text(0) == "Performer (none loaded)"


# ---------------------------------------------------------------------------- model -> widget
def test_pair_pushed_on_the_document_shows_everywhere(panel, doc):
    push_pair(doc, "LeftArm", "LeftShoulder")
    assert panel.model.rows == [("LeftArm", "LeftShoulder", "")]
    assert panel.target_tree.state("LeftArm") == "mapped"
    assert panel.performer_tree.state("LeftShoulder") == "mapped"
    assert panel.performer_tree.state("LeftCollar") == "unmapped"
    assert "LeftShoulder" in panel.target_tree.items["LeftArm"].toolTip(0)
    assert pairs_drawn(panel) == {"LeftArm": "LeftShoulder"}
    doc.undo_stack.undo()
    assert panel.model.rowCount() == 0
    assert panel.target_tree.state("LeftArm") == "required"
    assert panel.links.segments() == []


def test_lines_only_for_visible_rows(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    drawn = pairs_drawn(panel)
    assert drawn and set(drawn.items()) <= set(doc.scene.correspondence.pairs.items())
    for target, performer, y0, y1, _sel in panel.links.segments():
        assert 0 <= y0 <= panel.links.height() and 0 <= y1 <= panel.links.height()
    # collapsing the target's root hides every line but the root's own
    panel.target_tree.items["Hips"].setExpanded(False)
    assert pairs_drawn(panel) == {"Hips": "Hips"}
    panel.target_tree.items["Hips"].setExpanded(True)
    assert pairs_drawn(panel) == drawn
    # a small panel: rows scrolled out of view draw nothing, scrolling brings them back
    panel.resize(560, 420)
    qtbot.waitUntil(lambda: panel.target_tree.item_centre_y("RThumb") is None,
                    timeout=WAIT_MS)
    assert "RThumb" not in pairs_drawn(panel)
    panel.target_tree.scrollToBottom()
    panel.performer_tree.scrollToBottom()
    assert pairs_drawn(panel).get("RThumb") == "RThumb"


def test_evaluation_error_is_shown(panel, doc):
    assert panel.error_label.isHidden()
    push_pair(doc, "LeftArm", "LeftShoulder")          # a limb alone cannot drive the body
    assert doc.scene.evaluation_error and doc.motion is None
    assert not panel.error_label.isHidden()
    assert doc.scene.evaluation_error in panel.error_label.text()
    push_correspondence(doc, auto(doc), "Auto-map")
    assert doc.motion is not None and panel.error_label.isHidden()


# ---------------------------------------------------------------------------- required joints
def test_required_joints_come_from_identify(doc):
    required = required_joints(doc.scene.target.skeleton)
    assert set(required) == {"Hips", "LowerBack", "Spine1", "Head", "LeftArm", "RightArm",
                             "LeftForeArm", "RightForeArm", "LeftHand", "RightHand",
                             "LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg", "LeftFoot",
                             "RightFoot"}
    assert required["LeftHand"] == "left wrist" and required["RightLeg"] == "right knee"


def test_required_fallback_is_the_root(monkeypatch, doc):
    def not_humanoid(_skeleton, positions=None):
        raise automap_module.MappingError("no humanoid")
    monkeypatch.setattr(automap_module, "identify", not_humanoid)
    assert required_joints(doc.scene.target.skeleton) == {"Hips": "root"}


def test_required_unmapped_flags_come_and_go(panel, doc):
    flagged = {n for n in panel.target_tree.items if panel.target_tree.state(n) == "required"}
    assert flagged == set(panel.required) and "LeftHand" in flagged
    assert panel.target_tree.state("LThumb") == "unmapped"          # not required
    assert panel.target_tree.items["LeftHand"].foreground(0).color().red() > 150
    assert not panel.required_label.isHidden()
    assert panel.required_label.text().startswith("16 required joints unmapped: Hips (hips)")
    assert all(n in panel.required_label.toolTip() for n in panel.required)
    push_correspondence(doc, auto(doc), "Auto-map")
    assert panel.unmapped_required() == []
    assert all(panel.target_tree.state(n) == "mapped" for n in panel.required)
    assert panel.required_label.isHidden()
    push_pair(doc, "LeftHand", None)
    assert panel.target_tree.state("LeftHand") == "required"
    assert panel.required_label.text() == "1 required joint unmapped: LeftHand (left wrist)"
    assert not panel.required_label.isHidden()
    doc.undo_stack.undo()
    assert panel.target_tree.state("LeftHand") == "mapped" and panel.required_label.isHidden()


# ---------------------------------------------------------------------------- widget -> model
def test_select_and_map_button(panel, doc, qtbot):
    click_joint(qtbot, panel.target_tree, "LeftArm")
    assert doc.selection == ("target", "LeftArm")
    click_joint(qtbot, panel.performer_tree, "LeftShoulder")
    assert doc.selection == ("performer", "LeftShoulder")
    assert panel.target_tree.selected_joint() == "LeftArm"     # kept while picking the pair
    assert panel.map_action.isEnabled()
    before = doc.undo_stack.count()
    qtbot.mouseClick(panel.map_button, LEFT)
    assert doc.scene.correspondence.pairs == {"LeftArm": "LeftShoulder"}
    assert doc.undo_stack.count() == before + 1
    assert doc.undo_stack.undoText() == "Map LeftArm to LeftShoulder"
    assert doc.selection == ("target", "LeftArm")
    assert panel.table.selected_targets() == ["LeftArm"]
    assert not panel.map_action.isEnabled()                    # already mapped so
    # the Edit menu's actions name the command
    undo = doc.undo_stack.createUndoAction(panel)
    redo = doc.undo_stack.createRedoAction(panel)
    assert undo.text() == "Undo Map LeftArm to LeftShoulder"
    doc.undo_stack.undo()
    assert doc.scene.correspondence.pairs == {} and panel.model.rowCount() == 0
    assert redo.text() == "Redo Map LeftArm to LeftShoulder"
    doc.undo_stack.redo()
    assert panel.model.rows[0][:2] == ("LeftArm", "LeftShoulder")
    assert panel.model.rows[0][2] == "set by hand"


def test_drop_performer_on_target_and_back(panel, doc):
    before = doc.undo_stack.count()
    event = drop(panel.target_tree, "LeftForeArm", "performer", "LeftElbow")
    assert event.isAccepted()
    assert doc.scene.correspondence.pairs == {"LeftForeArm": "LeftElbow"}
    assert doc.undo_stack.count() == before + 1
    assert doc.undo_stack.undoText() == "Map LeftForeArm to LeftElbow"
    # the other way: a target joint dropped on a performer joint
    drop(panel.performer_tree, "RightKnee", "target", "RightLeg")
    assert doc.scene.correspondence.pairs == {"LeftForeArm": "LeftElbow", "RightLeg": "RightKnee"}
    assert doc.undo_stack.undoText() == "Map RightLeg to RightKnee"
    # a joint dropped on its own tree does nothing
    count = doc.undo_stack.count()
    event = drop(panel.target_tree, "Head", "target", "Neck")
    assert not event.isAccepted() and doc.undo_stack.count() == count
    # taking a performer joint from another target joint is still one command
    drop(panel.target_tree, "RightForeArm", "performer", "LeftElbow")
    assert doc.scene.correspondence.pairs == {"RightLeg": "RightKnee", "RightForeArm": "LeftElbow"}
    doc.undo_stack.undo()
    assert doc.scene.correspondence.pairs == {"LeftForeArm": "LeftElbow", "RightLeg": "RightKnee"}


def test_drag_payload_round_trip():
    mime = JointTree.mime_data("performer", "Left Hand 2")
    assert JointTree.decode(mime) == ("performer", "Left Hand 2")
    assert JointTree.decode(QtCore.QMimeData()) is None


def test_automap_button_is_one_command(panel, doc, qtbot):
    before = doc.undo_stack.count()
    qtbot.mouseClick(panel.automap_button, LEFT)
    expected = auto(doc)
    assert doc.scene.correspondence.pairs == expected.pairs
    assert doc.undo_stack.count() == before + 1
    assert doc.undo_stack.undoText() == "Auto-map"
    assert [r[0] for r in panel.model.rows] == list(expected.pairs)
    assert panel.model.rows[0][2] == expected.notes["Hips"]            # the automap note
    assert doc.motion is not None and not doc.scene.evaluation_error
    qtbot.mouseClick(panel.automap_button, LEFT)       # already so: no empty step
    assert doc.undo_stack.count() == before + 1
    doc.undo_stack.undo()
    assert len(doc.scene.correspondence) == 0 and doc.motion is None


def test_automap_failure_is_reported(panel, doc, monkeypatch):
    errors = []
    monkeypatch.setattr(panel, "show_error", lambda title, text: errors.append(text))

    def fail(*_args, **_kw):
        raise automap_module.MappingError("the skeleton's arms and head do not branch")
    monkeypatch.setattr(automap_module, "automap", fail)
    count = doc.undo_stack.count()
    panel.automap_action.trigger()
    assert errors and "do not branch" in errors[0]
    assert doc.undo_stack.count() == count and len(doc.scene.correspondence) == 0


def test_unmap_from_tree_selection_and_table(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    n = len(doc.scene.correspondence)
    click_joint(qtbot, panel.target_tree, "LeftHand")
    assert panel.table.selected_targets() == ["LeftHand"]
    qtbot.mouseClick(panel.unmap_button, LEFT)
    assert "LeftHand" not in doc.scene.correspondence.pairs and len(doc.scene.correspondence) == n - 1
    assert doc.undo_stack.undoText() == "Unmap LeftHand"
    assert not panel.unmap_action.isEnabled()
    # several table rows: one command
    model = panel.model
    rows = [model.row_of("LThumb"), model.row_of("RThumb")]
    selection = QtCore.QItemSelection()
    for r in rows:
        selection.select(model.index(r, 0), model.index(r, 2))
    panel.table.selectionModel().select(
        selection, QtCore.QItemSelectionModel.SelectionFlag.ClearAndSelect)
    assert doc.selection[0] == "target" and doc.selection[1] in ("LThumb", "RThumb")
    assert sorted(panel.table.selected_targets()) == ["LThumb", "RThumb"]   # kept both
    count = doc.undo_stack.count()
    panel.unmap_action.trigger()
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Unmap LThumb, RThumb"
    assert len(doc.scene.correspondence) == n - 3
    doc.undo_stack.undo()
    doc.undo_stack.undo()
    assert len(doc.scene.correspondence) == n


def test_delete_key_unmaps(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    # shortcuts only fire in the active window
    with qtbot.waitActive(panel, timeout=WAIT_MS):
        panel.activateWindow()
    click_joint(qtbot, panel.target_tree, "Head")
    panel.target_tree.setFocus()
    qtbot.keyClick(panel.target_tree, Qt.Key.Key_Delete)
    assert "Head" not in doc.scene.correspondence.pairs
    assert doc.undo_stack.undoText() == "Unmap Head"


def test_clear(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    qtbot.mouseClick(panel.clear_button, LEFT)
    assert len(doc.scene.correspondence) == 0 and panel.model.rowCount() == 0
    assert doc.undo_stack.undoText() == "Clear mapping"
    assert not panel.clear_action.isEnabled()
    doc.undo_stack.undo()
    assert doc.scene.correspondence.pairs == auto(doc).pairs


def test_table_combo_edits_the_performer(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    index = panel.model.index(panel.model.row_of("LeftArm"), 1)
    panel.table.setCurrentIndex(index)
    panel.table.edit(index)
    combo = panel.table.findChild(QtWidgets.QComboBox)
    assert combo is not None and combo.currentData() == "LeftShoulder"
    assert combo.count() == doc.scene.performer.skeleton.num_joints + 1
    i = combo.findData("LeftCollar")
    assert "\u2190 LeftShoulder" in combo.itemText(i)             # shows what it drives now
    combo.setCurrentIndex(i)
    combo.activated.emit(i)
    assert doc.scene.correspondence.pairs["LeftArm"] == "LeftCollar"
    assert "LeftShoulder" not in doc.scene.correspondence.pairs          # taken from it: one to one
    # the pair it replaces is named
    assert doc.undo_stack.undoText() == \
        "Map LeftArm to LeftCollar (replaces LeftShoulder -> LeftCollar)"
    qtbot.waitUntil(lambda: panel.table.findChild(QtWidgets.QComboBox) is None
                    or not panel.table.findChild(QtWidgets.QComboBox).isVisible(),
                    timeout=WAIT_MS)
    # "(unmapped)" unmaps
    index = panel.model.index(panel.model.row_of("Head"), 1)
    panel.table.edit(index)
    combo = [c for c in panel.table.findChildren(QtWidgets.QComboBox) if c.isVisible()][0]
    combo.setCurrentIndex(0)
    combo.activated.emit(0)
    assert "Head" not in doc.scene.correspondence.pairs
    assert doc.undo_stack.undoText() == "Unmap Head"
    doc.undo_stack.undo()
    doc.undo_stack.undo()
    assert doc.scene.correspondence.pairs == auto(doc).pairs


# ---------------------------------------------------------------------------- filter
def test_filter_hides_non_matching_joints(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    qtbot.keyClicks(panel.filter_edit, "HAND")
    tt, pt = panel.target_tree, panel.performer_tree
    shown_t = {n for n in tt.items if tt.is_shown(n)}
    shown_p = {n for n in pt.items if pt.is_shown(n)}
    assert {"LeftHand", "RightHand", "LeftHandIndex1"} <= shown_t
    # ancestors of matches stay visible, everything else is hidden
    assert {"Hips", "Spine1", "LeftShoulder", "LeftArm", "LeftForeArm"} <= shown_t
    assert not shown_t & {"LeftUpLeg", "Head", "LThumb", "RightToeBase"}
    assert {"lhand", "rhand", "LeftWrist", "Hips"} <= shown_p
    assert not shown_p & {"LeftHip", "Head", "LFingers"}
    for target, performer, *_ in panel.links.segments():
        assert tt.is_shown(target) and pt.is_shown(performer)
    assert "Head" not in pairs_drawn(panel)
    panel.filter_edit.clear()
    assert all(tt.is_shown(n) for n in tt.items) and all(pt.is_shown(n) for n in pt.items)


# ---------------------------------------------------------------------------- selection
def test_document_selection_shows_in_the_panel(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    panel.resize(560, 420)
    qtbot.waitUntil(lambda: panel.target_tree.item_centre_y("RThumb") is None,
                    timeout=WAIT_MS)
    doc.select("target", "RThumb")
    assert panel.target_tree.selected_joint() == "RThumb"
    assert panel.performer_tree.selected_joint() == "RThumb"        # its performer joint
    assert panel.target_tree.item_centre_y("RThumb") is not None      # scrolled to
    assert panel.table.selected_targets() == ["RThumb"]
    assert [s for s in panel.links.segments() if s[4]] and \
        all(s[0] == "RThumb" for s in panel.links.segments() if s[4])
    doc.select("performer", "LeftKnee")
    assert panel.performer_tree.selected_joint() == "LeftKnee"
    assert panel.target_tree.selected_joint() == "RThumb"           # kept for mapping
    assert panel.table.selected_targets() == ["LeftLeg"]            # the pair it is in
    doc.select("", "")
    assert panel.target_tree.selected_joint() is None
    assert panel.performer_tree.selected_joint() is None
    assert panel.table.selected_targets() == []


def test_widget_selection_sets_the_document_without_feedback(panel, doc, qtbot):
    push_correspondence(doc, auto(doc), "Auto-map")
    seen = []
    doc.selectionChanged.connect(lambda side, joint: seen.append((side, joint)))
    click_joint(qtbot, panel.target_tree, "LeftFoot")
    assert seen == [("target", "LeftFoot")]
    row = panel.model.row_of("Head")
    panel.table.scrollTo(panel.model.index(row, 0))
    rect = panel.table.visualRect(panel.model.index(row, 0))
    qtbot.mouseClick(panel.table.viewport(), LEFT, pos=rect.center())
    assert seen == [("target", "LeftFoot"), ("target", "Head")]
    assert panel.target_tree.selected_joint() == "Head"
    assert panel.performer_tree.selected_joint() == "Head"
    doc.select("performer", "LeftWrist")
    assert seen[-1] == ("performer", "LeftWrist") and len(seen) == 3


# ---------------------------------------------------------------------------- presets
def test_preset_round_trip(panel, doc, tmp_path, monkeypatch):
    push_correspondence(doc, auto(doc), "Auto-map")
    expected = doc.scene.correspondence
    monkeypatch.setattr(panel, "ask_save_path", lambda: str(tmp_path / "cmu"))
    panel.save_action.trigger()
    saved = tmp_path / "cmu.json"
    assert json.loads(saved.read_text())["pairs"] == expected.pairs
    panel.clear()
    assert len(doc.scene.correspondence) == 0
    monkeypatch.setattr(panel, "ask_load_path", lambda: str(saved))
    count = doc.undo_stack.count()
    panel.load_button.click()
    assert doc.scene.correspondence.pairs == expected.pairs
    assert doc.scene.correspondence.notes == expected.notes
    assert doc.undo_stack.count() == count + 1
    assert doc.undo_stack.undoText() == "Load preset cmu.json"
    assert doc.motion is not None


@pytest.mark.parametrize("content, message", [
    ("{ not json", "not valid JSON"),
    ('{"format": "motion-composer-mapping"}', '"pairs"'),
    ('{"pairs": {"Hips": "Hips", "LeftArm": "NoSuchJoint"}}', "NoSuchJoint"),
    ('{"pairs": {"Hips": "Hips", "Head": "Hips"}}', "several target joints"),
])
def test_bad_preset_shows_an_error_and_changes_nothing(panel, doc, tmp_path, monkeypatch,
                                                       content, message):
    push_pair(doc, "Hips", "Hips")
    path = tmp_path / "bad.json"
    path.write_text(content)
    errors = []
    monkeypatch.setattr(panel, "show_error", lambda title, text: errors.append((title, text)))
    monkeypatch.setattr(panel, "ask_load_path", lambda: str(path))
    count, pairs = doc.undo_stack.count(), dict(doc.scene.correspondence.pairs)
    panel.load_action.trigger()
    assert len(errors) == 1 and message in errors[0][1], errors
    assert doc.undo_stack.count() == count and doc.scene.correspondence.pairs == pairs
    # the panel keeps working
    panel.auto_map()
    assert len(doc.scene.correspondence) > 1


def test_missing_preset_and_unwritable_folder(panel, doc, tmp_path, monkeypatch):
    push_correspondence(doc, auto(doc), "Auto-map")
    errors = []
    monkeypatch.setattr(panel, "show_error", lambda title, text: errors.append(text))
    monkeypatch.setattr(panel, "ask_load_path", lambda: str(tmp_path / "gone.json"))
    panel.load_preset()
    assert "no such mapping file" in errors[-1]
    monkeypatch.setattr(panel, "ask_save_path",
                        lambda: str(tmp_path / "no" / "such" / "folder" / "map.json"))
    panel.save_preset()
    assert len(errors) == 2 and "Cannot save" in errors[-1]
    monkeypatch.setattr(panel, "ask_save_path", lambda: None)      # cancelled
    panel.save_preset()
    assert len(errors) == 2


# ---------------------------------------------------------------------------- evaluation
def test_changing_the_mapping_reconverts_the_motion(panel, doc, qtbot):
    qtbot.mouseClick(panel.automap_button, LEFT)
    first = doc.motion
    assert first is not None
    j = doc.scene.target.skeleton.index["LeftForeArm"]
    with qtbot.waitSignal(doc.motionChanged, timeout=WAIT_MS):
        drop(panel.target_tree, "LeftForeArm", "performer", "LeftShoulder")
    # LeftForeArm now follows the performer's upper arm; LeftArm lost it and follows its parent
    assert doc.motion is not None and doc.motion is not first
    assert not np.allclose(doc.motion.rotations[:, j], first.rotations[:, j], atol=1e-3)
    with qtbot.waitSignal(doc.motionChanged, timeout=WAIT_MS):
        doc.undo_stack.undo()
    np.testing.assert_allclose(doc.motion.rotations, first.rotations, atol=1e-12)


@pytest.mark.shared_data
@pytest.mark.parametrize("name", ["bandai1_walk_normal_001.bvh", "cc3_cmu_02_01_walk.bvh",
                                  "rokoko_mixamo_jesse_dance.bvh"])
def test_other_conventions_as_target(qtbot, clips, name):
    """Targets with a ground root (Bandai's joint_Root, CC3's RL_BoneRoot), helper joints and
    fingers: auto-mapping leaves no required joint unmapped, the ground root is not flagged."""
    target = read_bvh(shared_path(name))
    doc = Document()
    push_sources(doc, performer=clips[0], target=target)
    panel = shown(qtbot, CorrespondencePanel(doc), 560, 800)
    assert len(panel.target_tree.items) == target.skeleton.num_joints
    assert panel.unmapped_required()
    panel.automap_action.trigger()
    assert panel.unmapped_required() == [] and panel.required_label.isHidden()
    assert not [n for n in panel.target_tree.items if panel.target_tree.state(n) == "required"]
    assert doc.motion is not None and panel.error_label.isHidden()
    assert panel.links.segments()
    doc.close()


# ---------------------------------------------------------------------------- screenshot
def test_screenshot(qtbot, clips, tmp_path):
    """A picture of the panel with a real mapping (as in docs/screenshots/correspondence.png): the
    FAIR performer orders its limbs differently from the CMU target, so lines cross."""
    doc = Document()
    push_sources(doc, performer=read_bvh(clip_path("fair1_child8_jumping.bvh")),
                 performer_path=clip_path("fair1_child8_jumping.bvh"),
                 target=clips[1], target_path=clip_path("cmu_rest_tpose.bvh"))
    panel = shown(qtbot, CorrespondencePanel(doc), 620, 860)
    panel.automap_action.trigger()
    push_pair(doc, "LeftHand", None)                 # one required joint left unmapped
    doc.select("target", "LeftArm")
    panel.target_tree.scrollToTop()
    panel.performer_tree.scrollToTop()
    qtbot.wait(50)
    assert panel.target_tree.state("LeftHand") == "required"
    assert len(panel.links.segments()) > 10
    image = panel.grab().toImage()
    assert image.width() >= 600 and not image.isNull()
    # not blank: many distinct colours (text, lines, icons)
    colours = {image.pixel(x, y) for x in range(0, image.width(), 7)
               for y in range(0, image.height(), 7)}
    assert len(colours) > 20
    assert image.save(str(tmp_path / "correspondence.png"))
    doc.close()


def test_a_control_joint_says_what_carries_it(qtbot, clips):
    """The robot's feet are IK targets under its root, not mapped: their rows say which limb
    carries them and whose turn they take, and say so no more once that limb is unmapped."""
    from motion_composer.engine.formats import read_character
    performer, _ = clips
    robot = shared_path("target_robot_expressive.glb")
    document = Document()
    push_sources(document, performer=performer, performer_path=clip_path("cmu_131_01_walk.bvh"),
                 target=read_character(robot).rest_motion(), target_path=robot)
    push_correspondence(document, auto(document), "Auto-map")
    widget = CorrespondencePanel(document)
    qtbot.addWidget(widget)
    tree = widget.target_tree
    tip = tree.items["FootL"].toolTip(0)
    assert tree.state("FootL") == "unmapped"
    assert "carried with LowerLegL" in tip and "LeftAnkle" in tip, tip
    assert "carried with LowerLegR" in tree.items["FootR"].toolTip(0)
    assert "follows its parent" in tree.items["PoleTargetL"].toolTip(0)
    push_pair(document, "LowerLegL", None)
    assert "follows its parent" in tree.items["FootL"].toolTip(0)
    assert "carried with LowerLegR" in tree.items["FootR"].toolTip(0)
    document.undo_stack.undo()
    assert "carried with LowerLegL" in tree.items["FootL"].toolTip(0)
    document.close()
