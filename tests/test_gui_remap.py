"""Replacing a skeleton re-maps: the pairs set by hand that still fit are kept, the rest is
auto-mapped, in one undoable command, and the correspondence panel counts the new map."""
from __future__ import annotations

import pytest

pytest.importorskip("PySide6")

from motion_composer.app.gui.qt import QtWidgets  # noqa: E402, F401  (Qt set up first)
from motion_composer.app.gui.correspondence_panel import CorrespondencePanel  # noqa: E402
from motion_composer.app.gui.document import Document  # noqa: E402
from conftest import clip_path  # noqa: E402
from motion_composer.engine.conversion.correspondence import BY_HAND, Correspondence  # noqa: E402
from motion_composer.engine.formats import read_motion  # noqa: E402
from motion_composer.engine.project import Source  # noqa: E402

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
CHILD = clip_path("fair1_child8_jumping.bvh")


@pytest.fixture
def doc(qtbot):
    d = Document()
    d.set_source("performer", read_motion(WALK), Source(str(WALK)), "Import performer")
    d.set_source("target", read_motion(TPOSE), Source(str(TPOSE)), "Import target")
    yield d
    d.close()


def test_importing_the_second_skeleton_auto_maps_in_the_same_command(doc):
    assert doc.undo_stack.count() == 2
    assert doc.undo_stack.undoText() == "Import target"
    assert doc.scene.ready and len(doc.scene.correspondence) > 15
    doc.undo_stack.undo()
    assert doc.scene.target is None and not len(doc.scene.correspondence)


def test_a_replaced_target_keeps_the_hand_pairs_that_fit_and_auto_maps_the_rest(qtbot, doc):
    panel = CorrespondencePanel(doc)
    qtbot.addWidget(panel)
    corr = doc.scene.correspondence
    # by hand: the CMU target's Head driven by the performer's Neck (the automatic map says
    # Head -> Head); and a hand pair naming a joint the child does not have
    pairs = dict(corr.pairs)
    pairs.pop("Neck", None)
    pairs["Head"] = "Neck"
    pairs["LeftHandIndex1"] = "LeftFingerBase"
    notes = {t: n for t, n in corr.notes.items() if t in pairs}
    notes["Head"] = notes["LeftHandIndex1"] = BY_HAND
    doc.edit("Map Head to Neck", correspondence=Correspondence(pairs, notes))
    before = doc.scene.correspondence
    count = doc.undo_stack.count()

    child = read_motion(CHILD)
    doc.set_source("target", child, Source(str(CHILD)), "Import target fair1")
    assert doc.undo_stack.count() == count + 1              # one command
    corr = doc.scene.correspondence
    assert corr.pairs["Head"] == "Neck"                     # set by hand, still fits
    assert "LeftHandIndex1" not in corr.pairs               # the child has no such joint
    assert set(corr.pairs) <= set(child.skeleton.names)
    assert len(set(corr.pairs.values())) == len(corr.pairs)            # one to one
    corr.validate(child.skeleton, doc.scene.performer.skeleton)
    assert doc.scene.ready, doc.scene.evaluation_error
    n = len(child.skeleton.names)
    assert panel.summary_label.text() == f"{len(corr)} of {n} target joints mapped"
    assert len(corr) <= n and not panel.error_label.text()

    doc.undo_stack.undo()                                   # the old target and its map
    assert doc.scene.target.skeleton.names == read_motion(TPOSE).skeleton.names
    assert doc.scene.correspondence is before


def test_a_replaced_performer_drops_what_falls_past_its_end(doc):
    from motion_composer.engine.correction.constraints import Constraint
    hand = doc.pose("target").positions[900, doc.scene.target.skeleton.index["LeftHand"]]
    doc.edit("Add reach", constraints=(Constraint("LeftHand", "position", {"point": hand},
                                                  880, 890, 910, 920, name="late"),))
    short = doc.scene.performer.frames(slice(0, 300))
    doc.set_source("performer", short, Source(None), "Import short performer")
    assert not doc.scene.constraints                       # past the new last frame
    assert doc.scene.ready
    doc.undo_stack.undo()
    assert [c.name for c in doc.scene.constraints] == ["late"]
